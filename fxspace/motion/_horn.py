"""Absolute orientation (Horn 1987, closed form with unit quaternions)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace._validate import _is_tracer, as_float_array, checked
from fxspace.errors import FxspaceError
from fxspace.rotations import quat_to_matrix

__all__ = ["absolute_orientation", "absolute_rotation", "RigidTransform", "apply_rigid"]


class RigidTransform(NamedTuple):
    """``R`` ``(3, 3)`` proper rotation and ``t`` ``(3,)``: ``x ↦ R x + t``."""

    R: Float[Array, "3 3"]
    t: Float[Array, " 3"]


def absolute_orientation(
    src: Float[Array, "k 3"],
    dst: Float[Array, "k 3"],
    weights: Float[Array, " k"] | None = None,
) -> RigidTransform:
    """Rigid transform minimising ``Σ_k w_k ||R src_k + t − dst_k||²`` (Horn 1987).

    Horn's closed form: with centred points and ``M = Σ w_k src_k dst_kᵀ``, the optimal
    rotation is the unit quaternion eigenvector of the largest eigenvalue of the symmetric
    4×4 matrix ``N(M)`` (Horn 1987, J. Opt. Soc. Am. A 4(4), the matrix N of §4); the
    translation is ``t = d̄ − R s̄`` (the centroid result of §2). A quaternion is
    always a proper rotation, so a reflection (``det = −1`` in the SVD solution) can never
    be returned — the reflection case of Kabsch/Umeyama is handled by construction.
    Needs ``k ≥ 3`` non-collinear points for a unique answer. O(k). Batched over leading
    axes via ``jax.vmap``; differentiable where the top eigenvalue is simple.

    **Returns:** ``RigidTransform(R, t)`` (unpacks as ``R, t = absolute_orientation(...)``).
    """
    src = as_float_array(src, "src", finite="allow")
    dst = as_float_array(dst, "dst", finite="allow")
    if src.ndim != 2 or src.shape[-1] != 3 or src.shape != dst.shape:
        raise FxspaceError(f"src and dst must both be (k, 3), got {src.shape} and {dst.shape}")
    if src.shape[0] < 3:
        raise FxspaceError(f"absolute_orientation needs at least 3 point pairs, got {src.shape[0]}")
    if weights is None:
        w = jnp.ones(src.shape[0], src.dtype)
    else:
        w = as_float_array(weights, "weights", min_frames=0).astype(src.dtype)
        if w.shape != src.shape[:1]:
            raise FxspaceError(f"weights must have shape ({src.shape[0]},), got {w.shape}")
        if not _is_tracer(w) and (bool(jnp.any(w < 0)) or not bool(jnp.sum(w) > 0)):
            raise FxspaceError("weights must be >= 0 with a positive sum")
    w = w / jnp.sum(w)
    sbar = jnp.sum(w[:, None] * src, axis=0)
    dbar = jnp.sum(w[:, None] * dst, axis=0)
    # scaled before the products: float32 points at 1e19 or 1e-25 neither overflow nor
    # underflow (the rotation does not depend on a common scale)
    sc = jnp.maximum(jnp.max(jnp.abs(src - sbar[None])), jnp.max(jnp.abs(dst - dbar[None])))
    sc = jnp.where(sc > 0, sc, 1.0)
    S = jnp.einsum("k,ka,kb->ab", w, (src - sbar[None]) / sc, (dst - dbar[None]) / sc)
    N = horn_matrix(S)
    _, vecs = jnp.linalg.eigh(N)
    q = vecs[:, -1]
    R = quat_to_matrix(q)
    return RigidTransform(R, dbar - R @ sbar)


def absolute_rotation(
    src: Float[Array, "k 3"],
    dst: Float[Array, "k 3"],
    weights: Float[Array, " k"] | None = None,
) -> Float[Array, "3 3"]:
    """Rotation about the origin minimising ``Σ_k w_k ||R src_k − dst_k||²`` (no
    translation): Horn's quaternion of the largest eigenvalue of ``N(M)`` with the
    *uncentred* ``M = Σ w src dstᵀ`` (Horn 1987 §4; the centroids of §2 are what a
    translation would absorb). Ha & Han §3.2 re-place the upper samples this way: both
    point clouds in the root frame, one rotation about the root. Needs 2 non-parallel
    points for a unique answer. Batched via ``jax.vmap``."""
    src = as_float_array(src, "src", finite="allow")
    dst = as_float_array(dst, "dst", finite="allow")
    if src.ndim != 2 or src.shape[-1] != 3 or src.shape != dst.shape:
        raise FxspaceError(f"src and dst must both be (k, 3), got {src.shape} and {dst.shape}")
    if src.shape[0] < 2:
        raise FxspaceError(f"absolute_rotation needs at least 2 point pairs, got {src.shape[0]}")
    w = jnp.ones(src.shape[0], src.dtype) if weights is None else jnp.asarray(weights, src.dtype)
    if w.shape != src.shape[:1]:
        raise FxspaceError(f"weights must have shape ({src.shape[0]},), got {w.shape}")
    sc = jnp.maximum(jnp.max(jnp.abs(src)), jnp.max(jnp.abs(dst)))
    sc = jnp.where(sc > 0, sc, 1.0)
    S = jnp.einsum("k,ka,kb->ab", w / jnp.sum(w), src / sc, dst / sc)
    _, vecs = jnp.linalg.eigh(horn_matrix(S))
    return quat_to_matrix(vecs[:, -1])


@checked
def apply_rigid(tf: RigidTransform, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """``R x + t`` for points ``x`` (any leading shape)."""
    x = jnp.asarray(x)
    return jnp.einsum("ab,...b->...a", tf.R, x) + tf.t.reshape((1,) * (x.ndim - 1) + (3,))


def horn_matrix(S: Float[Array, "3 3"]) -> Float[Array, "4 4"]:
    """Horn's symmetric 4×4 matrix ``N`` of a cross-covariance ``S = Σ w src dstᵀ`` (Horn 1987,
    §4): the best rotation is the unit quaternion (w, x, y, z) eigenvector of its largest
    eigenvalue."""
    sxx, sxy, sxz = S[0, 0], S[0, 1], S[0, 2]
    syx, syy, syz = S[1, 0], S[1, 1], S[1, 2]
    szx, szy, szz = S[2, 0], S[2, 1], S[2, 2]
    N = jnp.stack(
        [
            jnp.stack([sxx + syy + szz, syz - szy, szx - sxz, sxy - syx]),
            jnp.stack([syz - szy, sxx - syy - szz, sxy + syx, szx + sxz]),
            jnp.stack([szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy]),
            jnp.stack([sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]),
        ]
    )
    return N
