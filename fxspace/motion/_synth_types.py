"""The data of decoupled parametric synthesis (Ha & Han): the two parametric spaces
(`SynthesisSpaces`, a JAX pytree), the clocks' state between frames (`SynthState`) and one
output frame (`Pose`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
from jaxtyping import Array, Float

from fxspace.motion._blend import ExampleSet

__all__ = ["SynthesisSpaces", "SynthState", "Pose"]


@dataclasses.dataclass(frozen=True)
class SynthesisSpaces:
    """The two parametric spaces ``P_L`` and ``P_U`` (a JAX pytree; see `build_spaces`).

    Arrays: ``lower``/``upper`` example sets (warps against their first example), ``lam``
    ``(N_L,)`` the alignment curve, ``offsets`` the skeleton's rest offsets, the lower samples
    ``lower_weights`` ``(S_L, E_L)`` / ``lower_params`` ``(S_L, d)``, the upper samples
    ``upper_weights`` ``(S_U, E_U)`` / ``upper_params`` ``(S_U, 3)`` (``ṗ``: root frame, for
    the initial lower blend ``lower_w0``), ``lower_time`` / ``upper_time`` (reference frames
    where each parameter is measured), ``posture_transfer``, ``joint_steps`` ``(J,)`` (each
    joint's largest step per example frame in any example, `example_joint_steps`: the
    joint-speed half of the bound). Static: ``parents``, ``mask``
    (upper-body joints), ``spine`` (splice joint), ``lower_joint``/``lower_dims``,
    ``upper_joint`` (``-1``: the upper parameter *is* the weight vector, as for the mood
    walk), ``k_replace`` (§3.2's ``k``), ``knn_k``, ``min_slope``, ``max_clock_rate`` (the
    bound on eqs. 2–3: after the alignment neither clock advances more than this × the
    eq.-(1) advance of the *fastest example of its own set at that phase*,
    ``max_i Δt / C_i'(T)`` — so α moves a body's tempo anywhere between its own blend's
    and the other's, but never past a captured clip's; ``inf``: eqs. 2–3 as printed,
    see `clock_bounds`; the continuous session also holds a frame's clock advance back
    where it would move a joint more than this × ``joint_steps``, `locomotion_step`),
    ``aligned`` (``False``: eq. 1 only, each body half on its own
    clock — Fig. 3(a), for measurement), ``splice`` (``"heck"``:
    `heck_splice`, spatial alignment + posture transfer; ``"heading"``: `splice_pose`) and
    ``torso`` (`torso_joints`, used by ``"heck"``), ``replace`` (§3.2's re-placement:
    ``"rotation"``, one rotation about the root as printed; ``"rigid"``, rotation and
    translation, Horn's full absolute orientation).
    """

    lower: ExampleSet
    upper: ExampleSet
    lam: Float[Array, " NL"]
    offsets: Float[Array, "J 3"]
    lower_weights: Float[Array, "SL EL"]
    lower_params: Float[Array, "SL d"]
    upper_weights: Float[Array, "SU EU"]
    upper_params: Float[Array, "SU 3"]
    lower_w0: Float[Array, " EL"]
    lower_time: Float[Array, ""]
    upper_time: Float[Array, ""]
    posture_transfer: Float[Array, ""]
    joint_steps: Float[Array, " J"]
    parents: tuple[int, ...]
    mask: tuple[bool, ...]
    spine: int
    lower_joint: int
    lower_dims: tuple[int, ...]
    upper_joint: int
    k_replace: int
    knn_k: int
    min_slope: float
    splice: str = "heck"
    torso: tuple[int, ...] = ()
    replace: str = "rotation"
    max_clock_rate: float = 1.0
    aligned: bool = True


jax.tree_util.register_dataclass(
    SynthesisSpaces,
    data_fields=[
        "lower", "upper", "lam", "offsets", "lower_weights", "lower_params", "upper_weights",
        "upper_params", "lower_w0", "lower_time", "upper_time", "posture_transfer",
        "joint_steps",
    ],
    meta_fields=[
        "parents", "mask", "spine", "lower_joint", "lower_dims", "upper_joint", "k_replace",
        "knn_k", "min_slope", "splice", "torso", "replace", "max_clock_rate", "aligned",
    ],
)  # fmt: skip


class SynthState(NamedTuple):
    """``t_lower``/``t_upper``: the reference clocks ``T_L``, ``T_U``; ``lower_param``: the
    lower parameter the upper samples were last re-placed for; ``upper_params`` ``(S_U, 3)``:
    those re-placed sample parameters; ``lower_weights``: the current lower blend."""

    t_lower: Float[Array, ""]
    t_upper: Float[Array, ""]
    lower_param: Float[Array, " d"]
    upper_params: Float[Array, "SU 3"]
    lower_weights: Float[Array, " EL"]


class Pose(NamedTuple):
    """One output frame: local joint quaternions ``(J, 4)`` and the root translation ``(3,)``."""

    rotations: Float[Array, "J 4"]
    root: Float[Array, " 3"]
