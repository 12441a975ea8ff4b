"""The one home of rigid and similarity fits, and of the best-fit plane.

`fit_similarity` solves, for point pairs ``src_k → dst_k`` with weights ``w_k ≥ 0``,

    min over R ∈ SO(3), s > 0, t   Σ_k w_k ‖s R src_k + t − dst_k‖²

in closed form (Umeyama 1991, IEEE PAMI 13(4), Lemma and eq. (40)–(42); Horn 1987's
absolute orientation when ``scale=False``): with the weighted centroids ``μ_s``, ``μ_d``
and the cross-covariance ``C = Σ w (dst − μ_d)(src − μ_s)ᵀ = U S Vᵀ``,
``R = U diag(1, 1, d) Vᵀ`` with ``d = sign det(U Vᵀ)`` — never a reflection —,
``s = Σ_i S_i D_ii / Σ_k w_k ‖src_k − μ_s‖²`` and ``t = μ_d − s R μ_s``. `fit_rotation`
is the same rotation without centroids (Wahba's problem, about the origin). O(n) for
``n`` pairs plus one 3 × 3 SVD; leading axes are batch axes (one fit each).

`principal_axes` and `best_fit_plane` are the weighted principal directions of a point
set (one SVD of the centred points): the plane through the centroid that minimises the
weighted squared distances has the least-spread axis as normal.

Every function accepts numpy arrays (computed in numpy, float64 for integer input, no
compilation) or JAX arrays (``jit``, ``vmap`` and ``grad`` work). The rotation's
derivative is taken implicitly from the optimality condition (``RᵀC`` symmetric), not
through the SVD, so it is finite wherever the optimal rotation is unique (rank C ≥ 2 and,
when ``det C < 0``, ``S_2 > S_3``) even when singular values repeat; where the rotation
is not unique (fewer than 3 non-collinear points of positive weight) its derivative is
set to zero.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import _is_tracer, check_dtype, checked
from fxspace.errors import FxspaceError

__all__ = [
    "SimilarityFit",
    "RotationFit",
    "fit_similarity",
    "fit_rotation",
    "principal_axes",
    "best_fit_plane",
]


class SimilarityFit(NamedTuple):
    """``dst ≈ scale · rotation @ src + translation``: ``rotation`` ``(..., 3, 3)``
    (``det = +1``), ``scale`` ``(...)`` (1 when fitted with ``scale=False``),
    ``translation`` ``(..., 3)``. Unpacks as ``R, s, t = fit_similarity(...)``."""

    rotation: Float[Array, "... 3 3"]
    scale: Float[Array, " ..."]
    translation: Float[Array, "... 3"]


class RotationFit(NamedTuple):
    """``dst ≈ rotation @ src`` (about the origin): ``rotation`` ``(..., 3, 3)``
    (``det = +1``) and the ``singular_values`` ``(..., 3)`` of the weighted
    cross-covariance ``Σ w dst srcᵀ`` (weights normalised to sum 1), descending: the
    rotation is unique when the second is clearly above zero."""

    rotation: Float[Array, "... 3 3"]
    singular_values: Float[Array, "... 3"]


def _xp(*arrays):
    """numpy for numpy inputs (readers, writers, one-off fits: no compilation), else jnp."""
    return np if all(isinstance(a, np.ndarray | np.generic) for a in arrays) else jnp


def _svd_rotation(xp, C):
    """``(R, S, d, U, Vt)``: the proper rotation maximising ``tr(RᵀC)`` (Umeyama's
    ``U diag(1, 1, d) Vᵀ``), the singular values of ``C = U S Vᵀ`` and the sign ``d``."""
    U, S, Vt = xp.linalg.svd(C)
    d = xp.sign(xp.linalg.det(U @ Vt))
    d = xp.where(d == 0, xp.ones_like(d), d)
    D = xp.stack([xp.ones_like(d), xp.ones_like(d), d], axis=-1)
    return (U * D[..., None, :]) @ Vt, S, d, U, Vt


@jax.custom_jvp
def _rotation_jax(C):
    """`_svd_rotation` under JAX, with the implicit derivative of the module docstring."""
    return _svd_rotation(jnp, C)[:2]


@_rotation_jax.defjvp
def _rotation_jax_jvp(primals, tangents):
    (C,), (dC,) = primals, tangents
    R, S, d, U, Vt = _svd_rotation(jnp, C)
    dS = jnp.einsum("...ia,...ij,...aj->...a", U, dC, Vt)  # u_aᵀ dC v_a
    # R(ε) = R exp(ε[ω]×) keeps K = RᵀC symmetric: [ω]×K + K[ω]× = E − Eᵀ with E = RᵀdC,
    # i.e. (tr K · I − K) ω = vee(E − Eᵀ); its eigenvalues are S₁+S₂, S₁+dS₃, S₂+dS₃
    K = jnp.swapaxes(R, -1, -2) @ C
    E = jnp.swapaxes(R, -1, -2) @ dC
    F = E - jnp.swapaxes(E, -1, -2)
    b = jnp.stack([F[..., 2, 1], F[..., 0, 2], F[..., 1, 0]], axis=-1)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=C.dtype), K.shape)
    A = jnp.trace(K, axis1=-2, axis2=-1)[..., None, None] * eye - K
    gap = S[..., 1] + d * S[..., 2]
    ok = gap > 16 * jnp.finfo(C.dtype).eps * S[..., 0]
    A = jnp.where(ok[..., None, None], A, eye)
    w = jnp.where(ok[..., None], jnp.linalg.solve(A, b[..., None])[..., 0], 0.0)
    z = jnp.zeros_like(w[..., 0])
    hat = jnp.stack(
        [
            jnp.stack([z, -w[..., 2], w[..., 1]], -1),
            jnp.stack([w[..., 2], z, -w[..., 0]], -1),
            jnp.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )
    return (R, S), (R @ hat, dS)


def _inputs(src, dst, weights, what="src and dst"):
    """``(xp, src, dst, w)`` checked: equal shapes ``(..., n, 3)``, weights ``(..., n)``
    (broadcast), concrete weights non-negative with a positive sum per fit."""
    xp = _xp(src, dst) if weights is None else _xp(src, dst, weights)
    if np.ndim(src) < 2 or np.shape(src)[-1] != 3 or np.shape(src) != np.shape(dst):
        if src is dst:
            raise FxspaceError(f"{what} must be (..., n, 3) points; got shape {np.shape(src)}")
        raise FxspaceError(
            f"{what} must both be (..., n, 3) with the same shape (point k of src pairs "
            f"with point k of dst); got {np.shape(src)} and {np.shape(dst)}"
        )
    if np.shape(src)[-2] < 1:
        raise FxspaceError(f"{what} hold no points; pass at least 3")
    dt = np.result_type(check_dtype(src, "src"), check_dtype(dst, "dst"))
    if xp is np:
        if np.result_type(np.asarray(src), np.asarray(dst)).kind in "iub":
            dt = np.dtype(np.float64)  # integer input: numpy computes in float64
        src, dst = np.asarray(src, dt), np.asarray(dst, dt)
    else:
        src, dst = jnp.asarray(src), jnp.asarray(dst)
        dt = jnp.promote_types(jnp.result_type(src, dst), jnp.float32)
        src, dst = src.astype(dt), dst.astype(dt)
    if weights is None:
        return xp, src, dst, xp.ones(src.shape[:-1], dt)
    check_dtype(weights, "weights")
    try:
        w = xp.broadcast_to(xp.asarray(weights, dt), src.shape[:-1])
    except ValueError:
        raise FxspaceError(
            f"weights must have shape {src.shape[:-1]} (one per point pair), "
            f"got {np.shape(weights)}"
        ) from None
    if not _is_tracer(w):
        wn = np.asarray(w)
        if not np.all(np.isfinite(wn)) or np.any(wn < 0):
            raise FxspaceError("weights must be finite and >= 0; give an outlier weight 0")
        if wn.size and np.all(wn.sum(-1) <= 0):
            raise FxspaceError(
                "weights are all 0: there is nothing to fit; give the points weight "
                "(within a batch, a fit with every weight 0 is the identity)"
            )
    return xp, src, dst, w


def _rotation(xp, C, w):
    """``(R, S)`` of a cross-covariance: numpy's SVD, or JAX's with the implicit JVP; the
    identity for a fit whose weights are all 0."""
    if xp is np:
        R, S = _svd_rotation(np, C)[:2]
    else:
        R, S = _rotation_jax(C)
    empty = xp.all(w <= 0, axis=-1)[..., None, None]
    return xp.where(empty, xp.broadcast_to(xp.eye(3, dtype=R.dtype), R.shape), R), S


def _normalised(xp, w):
    """Weights summing to 1 per fit; a traced all-zero row (a frame with no marker seen,
    under jit) stays 0, giving a finite placeholder fit (``C = 0``) rather than NaN."""
    n = xp.sum(w, axis=-1, keepdims=True)
    return w / xp.where(n > 0, n, xp.ones_like(n))


def _moments(xp, src, dst, w, centre: bool):
    """Normalised weights' centroids, the (scaled) centred points and the scale used.

    Points of weight 0 are zeroed first (NaN there is ignored). The centred points are
    divided by their largest magnitude before any product, so float32 points at 1e19 or
    1e-25 neither overflow nor underflow (R and s do not depend on a common scale)."""
    w = _normalised(xp, w)
    keep = (w > 0)[..., None]
    src = xp.where(keep, src, xp.zeros_like(src))
    dst = xp.where(keep, dst, xp.zeros_like(dst))
    if centre:
        ms = xp.einsum("...k,...ka->...a", w, src)
        md = xp.einsum("...k,...ka->...a", w, dst)
    else:
        ms = md = xp.zeros(src.shape[:-2] + (3,), src.dtype)
    xs = xp.where(keep, src - ms[..., None, :], 0.0)
    xd = xp.where(keep, dst - md[..., None, :], 0.0)
    sc = xp.maximum(xp.max(xp.abs(xs), axis=(-2, -1)), xp.max(xp.abs(xd), axis=(-2, -1)))
    sc = xp.where(sc > 0, sc, xp.ones_like(sc))[..., None, None]
    if xp is jnp:
        sc = jax.lax.stop_gradient(sc)
    return w, ms, md, xs / sc, xd / sc, sc


@checked
def fit_similarity(
    src: Float[Array, "... n 3"],
    dst: Float[Array, "... n 3"],
    weights: Float[Array, "... n"] | None = None,
    *,
    scale: bool = True,
) -> SimilarityFit:
    """The similarity (or, with ``scale=False``, the rigid motion) taking ``src`` onto
    ``dst`` in weighted least squares, never a reflection (Umeyama 1991; module docstring).

    **Arguments:**

    - `src`, `dst`: ``(..., n, 3)`` paired points (leading axes: one fit each). Needs 3
      non-collinear points of positive weight for a unique rotation.
    - `weights`: ``(..., n)`` (or broadcastable to it) non-negative weights, not all 0; a
      point of weight 0 is ignored, NaN coordinates included; a fit of a batch whose
      weights are all 0 (a frame with no marker seen) is the identity. Default: 1.
    - `scale`: fit the scale ``s`` (Umeyama); ``False`` keeps ``s = 1`` (Kabsch / Horn).

    **Returns:** `SimilarityFit` ``(rotation, scale, translation)`` with
    ``dst ≈ scale · rotation @ src + translation`` — numpy arrays for numpy input.
    """
    xp, src, dst, w = _inputs(src, dst, weights)
    w, ms, md, xs, xd, _ = _moments(xp, src, dst, w, centre=True)
    C = xp.einsum("...k,...ka,...kb->...ab", w, xd, xs)
    R, S = _rotation(xp, C, w)
    if scale:
        var = xp.einsum("...k,...ka,...ka->...", w, xs, xs)
        num = xp.einsum("...ab,...ab->...", R, C)  # tr(RᵀC) = Σ S_i D_ii
        s = xp.where(var > 0, num / xp.where(var > 0, var, xp.ones_like(var)), 1.0)
    else:
        s = xp.ones(src.shape[:-2], src.dtype)
    s = xp.asarray(s, src.dtype)
    t = md - s[..., None] * xp.einsum("...ab,...b->...a", R, ms)
    return SimilarityFit(R, s, t)


@checked
def fit_rotation(
    src: Float[Array, "... n 3"],
    dst: Float[Array, "... n 3"],
    weights: Float[Array, "... n"] | None = None,
) -> RotationFit:
    """The rotation about the origin taking the vectors ``src`` onto ``dst`` in weighted
    least squares, ``min Σ w_k ‖R src_k − dst_k‖²`` over proper rotations (Wahba's problem:
    the rotation of `fit_similarity` without centroids; scipy's ``align_vectors``).

    **Arguments:**

    - `src`, `dst`: ``(..., n, 3)`` paired vectors (leading axes: one fit each). Needs 2
      non-parallel vectors of positive weight for a unique rotation.
    - `weights`: ``(..., n)`` non-negative weights, not all 0 (as in `fit_similarity`).
      Default: 1.

    **Returns:** `RotationFit` ``(rotation, singular_values)``: ``rotation`` ``(..., 3,
    3)``, ``det = +1``; the singular values of the normalised cross-covariance say how
    well the rotation is determined (the second near 0: a spin about one axis is free).
    """
    xp, src, dst, w = _inputs(src, dst, weights)
    w, _, _, xs, xd, sc = _moments(xp, src, dst, w, centre=False)
    R, S = _rotation(xp, xp.einsum("...k,...ka,...kb->...ab", w, xd, xs), w)
    return RotationFit(R, S * sc[..., 0] ** 2)


@checked
def principal_axes(
    points: Float[Array, "... n 3"], weights: Float[Array, "... n"] | None = None
) -> tuple[Float[Array, "... 3"], Float[Array, "... 3 3"]]:
    """Weighted centroid and principal axes of a point set (PCA by one SVD of the centred
    points, each row scaled by ``√w``).

    **Arguments:**

    - `points`: ``(..., n, 3)`` (leading axes: one set each).
    - `weights`: ``(..., n)`` non-negative, not all 0. Default: 1.

    **Returns:** ``(centroid (..., 3), axes (..., 3, 3))``, the axes as rows, unit
    length, by decreasing spread: ``axes[0]``, ``axes[1]`` span the best-fit plane and
    ``axes[2]`` is its normal. Each axis's sign is the SVD's (not normalised).
    """
    if np.ndim(points) >= 2 and np.shape(points)[-2] < 3:
        raise FxspaceError(
            f"points must hold at least 3 points (..., n >= 3, 3), got shape {np.shape(points)}"
        )
    xp, p, _, w = _inputs(points, points, weights, "points")
    if weights is None:
        mu = p.mean(axis=-2)
        q = p - mu[..., None, :]
    else:
        w = _normalised(xp, w)
        keep = (w > 0)[..., None]
        mu = xp.einsum("...k,...ka->...a", w, xp.where(keep, p, 0.0))
        q = xp.where(keep, (p - mu[..., None, :]) * xp.sqrt(w)[..., None], 0.0)
    _, _, vt = xp.linalg.svd(q, full_matrices=False)
    return mu, vt


@checked
def best_fit_plane(
    points: Float[Array, "... n 3"], weights: Float[Array, "... n"] | None = None
) -> tuple[Float[Array, "... 3"], Float[Array, "... 3"]]:
    """The plane minimising the weighted squared distances of ``points`` to it: through
    the weighted centroid, normal to the least-spread principal axis (`principal_axes`).

    **Arguments:**

    - `points`: ``(..., n, 3)``, at least 3 (leading axes: one plane each).
    - `weights`: ``(..., n)`` non-negative, not all 0. Default: 1.

    **Returns:** ``(centroid (..., 3), normal (..., 3))``, the normal of unit length (its
    sign is the SVD's: flip it to face a chosen side).
    """
    mu, axes = principal_axes(points, weights)
    return mu, axes[..., 2, :]
