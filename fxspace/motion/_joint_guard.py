"""The examples' joint-speed envelope: how far each joint ever moves in one frame of a
captured clip. The continuous session (`locomotion_step`) holds its clocks back on the
rare frame where eqs. 1–3 would move a joint further than that (the default bound on
the clocks, ``SynthesisSpaces.max_clock_rate``; ``inf`` lifts it: eqs. 2–3 as printed).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.motion._blend import ExampleSet
from fxspace.motion._fk import fk_arrays

__all__ = ["example_joint_steps"]


@checked
def example_joint_steps(
    lower: ExampleSet,
    upper: ExampleSet,
    parents: tuple[int, ...],
    offsets: Float[Array, "J 3"],
) -> Float[Array, " J"]:
    """Each joint's largest world displacement between two consecutive frames of any
    example clip of either set (metres per example frame): the fastest captured clip's
    same joint. Padding frames (the last frame repeated, see `ExampleSet`) add nothing.

    **Arguments:** ``lower``, ``upper`` the two example sets of a `SynthesisSpaces`;
    ``parents``, ``offsets`` the skeleton.

    **Returns:** ``(J,)`` (a JAX array; O(E · T · J log depth) once, at build time).

    Example: a clip whose only joint moves 0.1 m per frame gives ``[0.1]``.
    """
    steps = []
    for ex, name in ((lower, "lower"), (upper, "upper")):
        rot, root = jnp.asarray(ex.rotations), jnp.asarray(ex.root)
        if rot.ndim != 4 or rot.shape[-2] != len(parents) or root.shape != rot.shape[:2] + (3,):
            raise FxspaceError(
                f"{name} must hold (E, T, {len(parents)}, 4) rotations and (E, T, 3) roots for "
                f"this skeleton, got {tuple(rot.shape)} and {tuple(root.shape)}"
            )
        if rot.shape[1] < 2:
            continue  # one frame: no step
        X = fk_arrays(parents, jnp.asarray(offsets, rot.dtype), root, rot)[0]  # (E, T, J, 3)
        valid = jnp.arange(1, rot.shape[1])[None, :] < jnp.asarray(ex.lengths)[:, None]
        d = jnp.linalg.norm(jnp.diff(X, axis=1), axis=-1)  # (E, T-1, J)
        steps.append(jnp.max(jnp.where(valid[..., None], d, 0.0), axis=(0, 1)))
    if not steps:
        raise FxspaceError("the example sets need a clip of at least two frames")
    return steps[0] if len(steps) == 1 else jnp.maximum(*steps)
