"""Absolute orientation (Horn 1987): the motion package's names for the one rigid fit of
`fxspace.rigid`, with their argument checks and the `RigidTransform` record."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace._validate import _is_tracer, as_float_array, checked
from fxspace.errors import FxspaceError
from fxspace.rigid import fit_rotation, fit_similarity

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

    The fit is `fxspace.rigid.fit_similarity` with ``scale=False`` (the package's one
    rigid fit): the optimal rotation of the centred points — the rotation Horn finds as
    the top eigenvector of his 4×4 matrix ``N`` (J. Opt. Soc. Am. A 4(4), §4), here by
    the equivalent SVD with the sign correction (Umeyama 1991), so never a reflection —
    and the translation ``t = d̄ − R s̄`` (Horn's centroid result, §2). Needs ``k ≥ 3``
    non-collinear points for a unique answer. O(k). Batched over leading axes via
    ``jax.vmap``; differentiable wherever the rotation is unique.

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
    R, _, t = fit_similarity(src, dst, w, scale=False)
    return RigidTransform(R, t)


def absolute_rotation(
    src: Float[Array, "k 3"],
    dst: Float[Array, "k 3"],
    weights: Float[Array, " k"] | None = None,
) -> Float[Array, "3 3"]:
    """Rotation about the origin minimising ``Σ_k w_k ||R src_k − dst_k||²`` (no
    translation): the rotation of Horn 1987 §4 for the *uncentred* ``M = Σ w src dstᵀ``
    (the centroids of §2 are what a translation would absorb), computed by
    `fxspace.rigid.fit_rotation`. Ha & Han §3.2 re-place the upper samples this way: both
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
    return fit_rotation(src, dst, w).rotation


@checked
def apply_rigid(tf: RigidTransform, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """``R x + t`` for points ``x`` (any leading shape)."""
    x = jnp.asarray(x)
    return jnp.einsum("ab,...b->...a", tf.R, x) + tf.t.reshape((1,) * (x.ndim - 1) + (3,))
