"""Forward kinematics of a :class:`~fxspace.io.Motion` (world joint positions, metres)."""

from __future__ import annotations

import numpy as np
from jaxtyping import Array, Float

from fxspace.rotations import _xp, quat_to_matrix

__all__ = ["forward_kinematics", "fk_arrays"]


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
    xp = _xp(offsets, root_translation, rotations)  # numpy in → numpy out (no compilation)
    parents_np = np.asarray(parents)
    J = len(parents)
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


def forward_kinematics(motion) -> Float[Array, "frames joints 3"]:
    """World joint positions ``(T, J, 3)`` in metres of a :class:`~fxspace.io.Motion`.

    Pure and jittable (``jax.jit(forward_kinematics)(mot)``: the skeleton is static);
    ``jax.vmap`` over clips stacked along a leading axis of the array fields works too.
    Joints sit at bone starts, end sites at bone tips (see :class:`~fxspace.io.Motion`).
    """
    parents = motion.parents
    if not isinstance(parents, tuple) or len(parents) == 0 or parents[0] != -1:
        raise ValueError("motion.parents must be a non-empty tuple starting with the root (-1)")
    if any(not (-1 <= p < j) for j, p in enumerate(parents)):
        raise ValueError("motion.parents must list parents before children (parents[j] < j)")
    if motion.rotations.shape[-2:] != (len(parents), 4):
        raise ValueError(
            f"motion.rotations must have shape (T, {len(parents)}, 4), got {motion.rotations.shape}"
        )
    return fk_arrays(parents, motion.offsets, motion.root_translation, motion.rotations)[0]
