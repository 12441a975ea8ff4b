"""Forward kinematics of a `Motion` (world joint positions, metres)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, checked
from fxspace.errors import FxspaceError
from fxspace.rotations import _xp, quat_to_matrix

if TYPE_CHECKING:
    from fxspace.motion._types import Motion

__all__ = ["forward_kinematics", "fk_arrays"]


def _check_parents(parents) -> np.ndarray:
    pa = np.asarray(parents) if isinstance(parents, list | tuple | np.ndarray) else None
    if pa is None or pa.ndim != 1 or pa.size == 0 or pa.dtype.kind not in "iu":
        raise FxspaceError(f"parents must be a non-empty tuple of joint indices, got {parents!r}")
    if np.any(pa < -1) or np.any(pa >= np.arange(pa.size)):
        raise FxspaceError("parents must list each joint's parent before it (-1 for a root)")
    return pa


def _check_fk_arrays(J: int, offsets, root_translation, rotations):
    """Float arrays of matching shapes; NumPy stays NumPy, NaN kept (NaN out)."""
    out = []
    for name, x in (("offsets", offsets), ("root_translation", root_translation),
                    ("rotations", rotations)):  # fmt: skip
        xp = "jax" if isinstance(x, jax.Array) else "numpy"
        out.append(as_float_array(x, name, finite="allow", xp=xp))
    offsets, root, rot = out
    lead = rot.shape[:-2]
    if offsets.shape != (J, 3):
        raise FxspaceError(f"offsets must have shape ({J}, 3) (joints, xyz), got {offsets.shape}")
    if rot.ndim < 2 or rot.shape[-2:] != (J, 4):
        raise FxspaceError(f"rotations must have shape (*frames, {J}, 4), got {rot.shape}")
    if root.shape != lead + (3,):
        raise FxspaceError(f"root_translation must have shape {lead + (3,)}, got {root.shape}")
    return offsets, root, rot


def fk_arrays(
    parents: tuple[int, ...],
    offsets: Float[Array, "joints 3"],
    root_translation: Float[Array, "*frames 3"],
    rotations: Float[Array, "*frames joints 4"],
) -> tuple[Float[Array, "*frames joints 3"], Float[Array, "*frames joints 3 3"]]:
    """World positions and world rotation matrices of every joint.

    ``R_w[j] = R_w[p] @ R(q_j)`` and ``X[j] = X[p] + R_w[p] @ offsets[j]`` with ``p = parents[j]``;
    ``X[root] = root_translation + offsets[root]``. ``parents`` is static (a tuple, parents
    first). The chains are composed by pointer jumping: ⌈log2(depth)⌉ steps of one gather
    and one batched 3×3 product each — O(T · J · log depth) work, a small graph to compile.
    """
    parents_np = _check_parents(parents)
    J = len(parents_np)
    offsets, root_translation, rotations = _check_fk_arrays(J, offsets, root_translation, rotations)
    xp = _xp(offsets, root_translation, rotations)  # numpy in → numpy out (no compilation)
    R = quat_to_matrix(rotations)  # (..., J, 3, 3)
    lead = R.shape[:-3]
    # local transforms (R_j, p_j): p_j = offsets[j], plus the root translation on the root
    root_mask = (parents_np < 0).astype(np.float64)[:, None]  # (J, 1)
    p = xp.broadcast_to(offsets, lead + (J, 3)) + root_translation[..., None, :] * xp.asarray(
        root_mask, dtype=offsets.dtype
    ).reshape((1,) * len(lead) + (J, 1))
    # pointer jumping (log2(depth) steps): A_j ← A_ptr(j) ∘ A_j, ptr(j) ← ptr(ptr(j));
    # (R_a, p_a) ∘ (R_b, p_b) = (R_a R_b, R_a p_b + p_a). Each step is one gather + matmul.
    ptr = parents_np.copy()
    while np.any(ptr >= 0):
        has = ptr >= 0
        src = np.where(has, ptr, np.arange(J))
        Ra, pa = R[..., src, :, :], p[..., src, :]
        Rn = Ra @ R
        pn = xp.einsum("...jab,...jb->...ja", Ra, p) + pa
        m = has.reshape((1,) * len(lead) + (J,))
        R = xp.where(m[..., None, None], Rn, R)
        p = xp.where(m[..., None], pn, p)
        ptr = np.where(has, ptr[src], -1)
    return p, R


@checked
def forward_kinematics(motion: Motion) -> Float[Array, "frames joints 3"]:
    """World joint positions ``(T, J, 3)`` in metres of a `Motion`.

    Pure and jittable (``jax.jit(forward_kinematics)(mot)``: the skeleton is static);
    ``jax.vmap`` over clips stacked along a leading axis of the array fields works too.
    Joints sit at bone starts, end sites at bone tips (see `Motion`).

    Quaternions are **normalised** first (an unnormalised one is a rotation scaled by its
    norm, which would stretch the bones); a zero quaternion is no rotation at all: it
    raises `FxspaceError` when the array is concrete and gives NaN positions under ``jit``.
    """
    parents = motion.parents
    if not isinstance(parents, tuple) or len(parents) == 0 or parents[0] != -1:
        raise FxspaceError("motion.parents must be a non-empty tuple starting with the root (-1)")
    if any(not (-1 <= p < j) for j, p in enumerate(parents)):
        raise FxspaceError("motion.parents must list parents before children (parents[j] < j)")
    if motion.rotations.shape[-2:] != (len(parents), 4):
        raise FxspaceError(
            f"motion.rotations must have shape (T, {len(parents)}, 4), got {motion.rotations.shape}"
        )
    q = motion.rotations
    xp = _xp(q)
    norm = xp.sqrt(xp.sum(q * q, axis=-1, keepdims=True))
    if not isinstance(q, jax.core.Tracer) and np.any(np.asarray(norm) == 0):
        bad = np.argwhere(np.asarray(norm)[..., 0] == 0)[0]
        raise FxspaceError(
            f"motion.rotations holds a zero quaternion at (frame, joint) {tuple(bad.tolist())};"
            " use (1, 0, 0, 0) for no rotation"
        )
    q = xp.where(norm > 0, q / xp.where(norm > 0, norm, 1.0), xp.nan)
    return fk_arrays(parents, motion.offsets, motion.root_translation, q)[0]
