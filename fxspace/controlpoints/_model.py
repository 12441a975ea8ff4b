"""Control-point model of a dense face segment (Hirose & Higuchi), reconstruction and editing.

Within one segment of ``T`` frames the vertex trajectories ``x_i(t)`` are approximated
from the first and last frames plus ``c`` control-point trajectories ``C_k(t)``:

    x̂_i(t) = L_i(t) + Σ_k w_ik R_k(t),    L_i(t) = x_i(0) + (t/(T−1)) (x_i(T−1) − x_i(0)),
    R_k(t) = C_k(t) − [C_k(0) + (t/(T−1)) (C_k(T−1) − C_k(0))],

i.e. every vertex follows the non-linear part of its cluster's control point on top of
its own linear in-between. ``w`` are membership weights (rows sum to 1): one-hot labels
from kernel k-means on the vertices' trajectories, optionally smoothed in space so that
vertices near a cluster border blend neighbouring control points. With one-hot weights
and ``C_k`` the mean trajectory of cluster ``k``, the paper's error (eq. (1))

    E = Σ_i Σ_t ‖x_i(t) − x̂_i(t)‖²

equals the k-means objective on the residual trajectories ``x_i − L_i``, which is why
clustering those trajectories picks good control points. Storage: first and last frames
(2·N·3 numbers), the control trajectories (c·(T−2)·3) and the labels (N) or the non-zero
weights (2 per entry, value + index).

Editing moves a control point by an offset over a smooth temporal window; every vertex
moves by its weight for that control point times the offset, so vertices with zero
weight — outside the cluster and its blending border — do not move.
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from fxspace._validate import (
    as_float_array,
    check_indices,
    check_int,
    check_scalar,
    check_scale,
    checked,
)
from fxspace.cluster import KernelKMeansResult, kernel_kmeans, median_gamma
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS

__all__ = [
    "ControlPointModel",
    "linear_interpolation",
    "reconstruction_error",
    "residual_trajectories",
    "blend_weights",
    "control_point_model",
    "fit_control_points",
    "ControlPointFit",
    "reconstruct",
    "edit_control_point",
    "temporal_window",
    "compression_ratio",
    "storage_size",
]


class ControlPointModel(NamedTuple):
    """A segment stored as key frames + control-point trajectories.

    **Fields:** ``first``/``last`` ``(N, 3)`` key frames; ``controls`` ``(c, T, 3)``
    control-point trajectories (only their non-linear part matters); ``weights`` ``(N, c)``
    blending weights (rows sum to 1); ``labels`` ``(N,)`` hard cluster of each vertex.
    """

    first: Float[Array, "N 3"]
    last: Float[Array, "N 3"]
    controls: Float[Array, "c T 3"]
    weights: Float[Array, "N c"]
    labels: Int[Array, " N"]


class ControlPointFit(NamedTuple):
    """Result of `fit_control_points`: the ``model`` and the kernel k-means
    ``clustering`` that placed its control points (unpacks as ``model, clustering``).

    ``result`` and ``stats`` are the clustering's (its fixed point reached:
    ``RESULTS.successful``); ``converged`` is derived from ``result``.
    """

    model: ControlPointModel
    clustering: KernelKMeansResult

    @property
    def result(self):
        return self.clustering.result

    @property
    def stats(self) -> dict:
        return self.clustering.stats

    @property
    def num_steps(self):
        return self.clustering.num_steps

    @property
    def converged(self):
        """``result == RESULTS.successful`` (derived, not stored)."""
        return self.result == RESULTS.successful


@checked
def linear_interpolation(
    first: Float[ArrayLike, ...], last: Float[ArrayLike, ...], n_frames: int
) -> Float[Array, "T ..."]:
    """``L(t) = first + (t/(T−1)) (last − first)`` for ``t = 0 … T−1`` (the baseline)."""
    first = jnp.asarray(first)
    last = jnp.asarray(last)
    if first.shape != last.shape:
        raise FxspaceError(f"first {first.shape} and last {last.shape} must have the same shape")
    if n_frames < 2:
        raise FxspaceError(f"n_frames must be >= 2; got {n_frames}")
    s = jnp.linspace(0.0, 1.0, n_frames, dtype=jnp.result_type(first.dtype, float))
    s = s.reshape((n_frames,) + (1,) * first.ndim)
    # (1 − s)·first + s·last reproduces both key frames exactly (segments stitch exactly)
    return (1.0 - s) * first[None] + s * last[None]


@checked
def reconstruction_error(X: Float[ArrayLike, "T ..."], X_hat: Float[ArrayLike, "T ..."]) -> Array:
    """The paper's eq. (1): ``Σ_i Σ_t ‖x_i(t) − x̂_i(t)‖²`` (sum of squares over everything)."""
    X = jnp.asarray(X)
    X_hat = jnp.asarray(X_hat)
    if X.ndim < 1:
        raise FxspaceError(f"X must be (T, ...) frames, got a scalar of shape {X.shape}")
    if X.shape != X_hat.shape:
        raise FxspaceError(f"X {X.shape} and X_hat {X_hat.shape} must have the same shape")
    return jnp.sum((X - X_hat) ** 2)


@checked
def residual_trajectories(X: Float[ArrayLike, "T N 3"]) -> Float[Array, "T N 3"]:
    """``x_i(t) − L_i(t)``: the part of the motion linear interpolation misses (0 at the ends)."""
    X = jnp.asarray(X)
    return X - linear_interpolation(X[0], X[-1], X.shape[0])


def _check_labels(labels, n: int, n_clusters: int) -> Array:
    """``labels`` as an int32 ``(n,)`` array of cluster indices in ``[0, n_clusters)``."""
    if isinstance(labels, jax.core.Tracer):
        return jnp.asarray(labels, jnp.int32)
    lab = check_indices(labels, "labels", n_clusters)
    if lab.shape[0] != n:
        raise FxspaceError(f"labels must hold one cluster index per vertex ({n}), got {lab.size}")
    return jnp.asarray(lab, jnp.int32)


def blend_weights(
    rest: Float[ArrayLike, "N 3"],
    labels: Int[ArrayLike, " N"],
    n_clusters: int,
    radius: float = 0.0,
    chunk: int = 1024,
) -> Float[Array, "N c"]:
    """Membership weights: one-hot labels smoothed by a Gaussian of spatial distance.

    ``w_ik ∝ Σ_j exp(−‖p_i − p_j‖² / (2 r²)) [label_j = k]`` on the rest positions ``p``;
    ``radius = 0`` gives the one-hot labels. O(N²) time, O(chunk·N) memory.
    """
    P = as_float_array(rest, "rest", shape=(None, 3))
    n_clusters = check_int(n_clusters, "n_clusters", low=1)
    radius = check_scalar(radius, "radius", low=0.0)
    chunk = check_int(chunk, "chunk", low=1)
    labels = _check_labels(labels, P.shape[0], n_clusters)
    H = jax.nn.one_hot(labels, n_clusters, dtype=P.dtype)
    if radius <= 0:
        return H
    N = P.shape[0]
    pad = (-N) % chunk
    Pp = jnp.pad(P, ((0, pad), (0, 0)))

    def rows(Pc):
        d2 = jnp.sum((Pc[:, None, :] - P[None, :, :]) ** 2, axis=-1)
        G = jnp.exp(-d2 / (2.0 * radius**2))
        W = G @ H
        return W / jnp.sum(W, axis=1, keepdims=True)

    W = jax.lax.map(rows, Pp.reshape(-1, chunk, 3))
    W = W.reshape(-1, n_clusters)[:N]
    return jnp.where(W > 1e-6, W, 0.0) / jnp.sum(jnp.where(W > 1e-6, W, 0.0), 1, keepdims=True)


def control_point_model(
    X: Float[ArrayLike, "T N 3"],
    labels: Int[ArrayLike, " N"],
    n_clusters: int,
    weights: Float[ArrayLike, "N c"] | None = None,
) -> ControlPointModel:
    """Model whose control points are the clusters' mean trajectories (``weights``: one-hot)."""
    X = as_float_array(X, "X", ndim=3, finite="allow")
    if X.shape[2] != 3 or X.shape[0] < 2:
        raise FxspaceError(f"X must be (frames >= 2, vertices, 3); got shape {tuple(X.shape)}")
    n_clusters = check_int(n_clusters, "n_clusters", low=1)
    labels = _check_labels(labels, X.shape[1], n_clusters)
    H = jax.nn.one_hot(labels, n_clusters, dtype=X.dtype)  # (N, c)
    sizes = jnp.sum(H, axis=0)
    C = jnp.einsum("nk,tnd->ktd", H, X) / jnp.maximum(sizes, 1.0)[:, None, None]
    if weights is None:
        W = H
    else:
        W = as_float_array(weights, "weights", shape=(X.shape[1], n_clusters)).astype(X.dtype)
    return ControlPointModel(X[0], X[-1], C, W, labels)


def _check_X(X) -> Array:
    if not isinstance(X, jax.Array):
        a = np.asarray(X)
        if a.dtype.kind not in "biuf":
            raise FxspaceError(
                f"X must be a numeric (frames, vertices, 3) array; got dtype {a.dtype}"
            )
    X = jnp.asarray(X)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 3:
        raise FxspaceError(f"X must be (frames >= 3, vertices, 3); got {X.shape}")
    if not jnp.issubdtype(X.dtype, jnp.floating):
        X = X.astype(jnp.result_type(float))
    return X


def _lloyd(F: Array, centres: Array, steps: int) -> tuple[Array, Array]:
    """``steps`` Euclidean k-means (Lloyd) steps from ``centres``; returns (labels, centres)."""
    c = centres.shape[0]
    sq = jnp.sum(F * F, axis=1)

    def assign(C):
        d = sq[:, None] - 2.0 * F @ C.T + jnp.sum(C * C, axis=1)[None, :]
        return jnp.argmin(d, axis=1).astype(jnp.int32)

    def body(_, C):
        lab = assign(C)
        H = jax.nn.one_hot(lab, c, dtype=F.dtype)
        n = jnp.sum(H, axis=0)
        return jnp.where(n[:, None] > 0, (H.T @ F) / jnp.maximum(n, 1.0)[:, None], C)

    C = jax.lax.fori_loop(0, steps, body, centres)
    return assign(C), C


_lloyd_jit = jax.jit(_lloyd, static_argnums=2)


def fit_control_points(
    X: Float[ArrayLike, "T N 3"],
    n_clusters: int,
    *,
    gamma: float | None = None,
    key: PRNGKeyArray | None = None,
    n_init: int = 20,
    blend_radius: float = 0.0,
    max_steps: int = 100,
    max_points: int | None = 1000,
    refine_steps: int = 10,
    method: Literal["kernel", "hybrid"] = "kernel",
) -> ControlPointFit:
    """Control points of a segment by kernel k-means on the vertices' residual trajectories.

    Each vertex is the point ``vec(x_i(t) − L_i(t))_{t=1…T−2}`` (3(T−2) numbers) divided by
    the RMS norm; Gaussian kernel k-means (`fxspace.kernel_kmeans`, ``n_init``
    restarts — the paper used 20) clusters them and each cluster's mean trajectory is a
    control point. ``gamma`` is the kernel width on these scaled trajectories (``None`` →
    median heuristic, on every vertex).

    Dense meshes (more than ``max_points`` vertices): the ``n_init`` restarts run on an
    evenly strided subset of ``max_points`` vertices (kernel k-means is O(N²) per step and
    restart), every vertex is assigned by ``refine_steps`` Euclidean k-means steps from the
    subset's clusters, and then

    - ``method="kernel"`` (the default, the paper's method to the end): kernel k-means on
      *every* vertex, started from those labels, runs to its fixed point: the final labels
      are kernel k-means' (one more step changes none);
    - ``method="hybrid"``: the Euclidean steps' labels are final (faster on big meshes;
      for one-hot weights eq. (1) is the Euclidean k-means objective, so those steps lower
      the reconstruction error directly, but the partition is no longer kernel k-means').

    ``max_points=None`` clusters every vertex with the restarts. ``blend_radius`` (units of
    ``X``) smooths the memberships across cluster borders (`blend_weights`, first frame).

    **Returns:** a `ControlPointFit` ``(model, clustering)`` (with ``.result``): the
    clustering of the final run (all vertices with ``method="kernel"``; the subset with
    ``"hybrid"``).
    """
    X = _check_X(X)
    check_scale(X, "X")  # overflow of the squared residuals: refuse, never "converged"
    T, N, _ = X.shape
    n_clusters = check_int(n_clusters, "n_clusters", low=1)
    n_init = check_int(n_init, "n_init", low=1)
    if max_points is not None:
        max_points = check_int(max_points, "max_points", low=max(1, n_clusters))
    if not 1 <= n_clusters <= N:
        raise FxspaceError(f"n_clusters must be in [1, {N}] (vertices); got {n_clusters}")
    if method not in ("kernel", "hybrid"):
        raise FxspaceError(
            f"method must be 'kernel' (kernel k-means to the end, the paper's) or 'hybrid'; "
            f"got {method!r}"
        )
    # Segments of every length would each compile their own programs: the frames are padded
    # to a size bucket (copies of the last frame, whose residuals are exactly zero), which
    # leaves every distance between the vertices' features — and so the clustering — as is.
    Xn = np.asarray(X)
    Xp = _pad_frames(Xn, frame_bucket(T))
    T_ = jnp.asarray(T, jnp.int32)
    if max_points is not None and N > max_points:
        idx = np.linspace(0, N - 1, max_points).round().astype(np.int64)
        sub = _subset_features(Xp, T_, jnp.asarray(idx))
        if method == "kernel" and gamma is None:
            gamma = float(median_gamma(_features(Xp, T_)))  # one γ for subset and all
        km = kernel_kmeans(sub, n_clusters, gamma, key=key, n_init=n_init, max_steps=max_steps)
        labels = _refine_labels(Xp, T_, sub, km.labels, n_clusters, int(refine_steps))
        if method == "kernel":
            km = kernel_kmeans(
                _features(Xp, T_), n_clusters, gamma, key=key, max_steps=max_steps,
                init=labels[None],
            )  # fmt: skip
            labels = km.labels
    else:
        feats = _features(Xp, T_)
        km = kernel_kmeans(feats, n_clusters, gamma, key=key, n_init=n_init, max_steps=max_steps)
        labels = km.labels
    first, last = jnp.asarray(Xn[0]), jnp.asarray(Xn[-1])
    W = blend_weights(first, labels, n_clusters, blend_radius) if blend_radius > 0 else None
    C = np.asarray(_cluster_means(Xp, labels, n_clusters))[:, :T]  # sliced on the host
    W = jax.nn.one_hot(labels, n_clusters, dtype=X.dtype) if W is None else W
    return ControlPointFit(ControlPointModel(first, last, jnp.asarray(C), W, labels), km)


def frame_bucket(n: int) -> int:
    """The padded length of an ``n``-frame segment: a multiple of a quarter of the power of
    two below ``n`` (at least 8), so at most 25 % padding and four sizes per octave."""
    n = int(n)
    step = max(8, (1 << max(n.bit_length() - 1, 0)) // 4)
    return -(-n // step) * step


def _pad_frames(Xn: np.ndarray, Tb: int) -> Array:
    """``Xn`` with copies of its last frame up to ``Tb`` frames (on the host: no program per
    length)."""
    if Tb > Xn.shape[0]:
        Xn = np.concatenate([Xn, np.repeat(Xn[-1:], Tb - Xn.shape[0], axis=0)])
    return jnp.asarray(Xn)


def _features_of(Xp: Array, T: Array) -> Array:
    """The scaled residual trajectories of the first ``T`` frames of padded ``Xp``, one row
    per vertex ``(N, 3·Tb)``: the ends and the padding are exact zeros."""
    Tb, N, _ = Xp.shape
    t = jnp.arange(Tb)
    s = jnp.clip(t.astype(Xp.dtype) / (T - 1).astype(Xp.dtype), 0.0, 1.0)[:, None, None]
    last = jax.lax.dynamic_index_in_dim(Xp, T - 1, keepdims=False)
    R = Xp - ((1.0 - s) * Xp[0][None] + s * last[None])
    R = jnp.where(((t > 0) & (t < T - 1))[:, None, None], R, 0.0)
    feats = jnp.moveaxis(R, 1, 0).reshape(N, -1)
    scale = jnp.sqrt(jnp.mean(jnp.sum(feats**2, axis=1)))
    return feats / jnp.where(scale > 0, scale, 1.0)


_features = jax.jit(_features_of)


@jax.jit
def _subset_features(Xp: Array, T: Array, idx: Array) -> Array:
    return _features_of(Xp, T)[idx]


@partial(jax.jit, static_argnums=(4, 5))
def _refine_labels(Xp, T, sub, sub_labels, n_clusters: int, steps: int) -> Array:
    """Every vertex assigned by ``steps`` Lloyd steps from the subset's cluster means."""
    feats = _features_of(Xp, T)
    H = jax.nn.one_hot(sub_labels, n_clusters, dtype=feats.dtype)
    C0 = (H.T @ sub) / jnp.maximum(jnp.sum(H, axis=0), 1.0)[:, None]
    return _lloyd(feats, C0, steps)[0]


@partial(jax.jit, static_argnums=2)
def _cluster_means(X: Array, labels: Array, n_clusters: int) -> Array:
    """Mean trajectory of each cluster ``(c, T, 3)`` (0 for an empty cluster)."""
    H = jax.nn.one_hot(labels, n_clusters, dtype=X.dtype)
    return jnp.einsum("nk,tnd->ktd", H, X) / jnp.maximum(jnp.sum(H, axis=0), 1.0)[:, None, None]


def _control_residuals(controls: Float[Array, "c T 3"]) -> Float[Array, "c T 3"]:
    T = controls.shape[1]
    s = jnp.linspace(0.0, 1.0, T, dtype=controls.dtype)[None, :, None]
    return controls - ((1.0 - s) * controls[:, :1] + s * controls[:, -1:])


@checked
@jax.jit
def reconstruct(model: ControlPointModel) -> Float[Array, "T N 3"]:
    """Rebuild the segment: ``x̂_i(t) = L_i(t) + Σ_k w_ik R_k(t)``. O(T·N·c); one program
    per segment length (jitted)."""
    T = model.controls.shape[1]
    L = linear_interpolation(model.first, model.last, T)
    return L + jnp.einsum("nk,ktd->tnd", model.weights, _control_residuals(model.controls))


@checked
def temporal_window(n_frames: int, center: float, width: float) -> Float[Array, " T"]:
    """Hann bump ``½(1 + cos(π (t − center)/width))`` for ``|t − center| < width``, else 0."""
    if not isinstance(width, jax.core.Tracer) and width <= 0:
        raise FxspaceError(f"width must be > 0 frames, got {width}")
    t = jnp.arange(n_frames, dtype=jnp.result_type(float))
    u = (t - center) / width
    return jnp.where(jnp.abs(u) < 1.0, 0.5 * (1.0 + jnp.cos(jnp.pi * u)), 0.0)


@checked
def edit_control_point(
    model: ControlPointModel,
    index: int | Int[Array, ""],
    offset: Float[ArrayLike, " 3"],
    center: float | None = None,
    width: float | None = None,
) -> ControlPointModel:
    """Move control point ``index`` by ``offset`` around frame ``center`` (Hann window).

    The control trajectory becomes ``C_k(t) + h(t)·offset`` with ``h`` the Hann bump of
    half-width ``width`` frames (defaults: the middle frame and half the segment), zero
    at the key frames; vertex ``i`` moves by ``w_ik h(t) offset`` — smoothly, and only where
    ``w_ik > 0``.
    """
    T = model.controls.shape[1]
    c = model.controls.shape[0]
    if isinstance(index, int | np.integer) and not 0 <= index < c:
        raise FxspaceError(f"index must be in [0, {c}) (control points); got {index}")
    off = jnp.asarray(offset, model.controls.dtype)
    if off.shape != (3,):
        raise FxspaceError(f"offset must be a 3-vector; got shape {off.shape}")
    if not isinstance(off, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(off))):
        raise FxspaceError(f"offset must be finite (no NaN/inf); got {np.asarray(off).tolist()}")
    center = (T - 1) / 2 if center is None else check_scalar(center, "center")
    width = (T - 1) / 2 if width is None else check_scalar(width, "width", low=0.0, low_open=True)
    h = temporal_window(T, center, width).astype(model.controls.dtype)
    h = h.at[0].set(0.0).at[-1].set(0.0)
    controls = model.controls.at[index].add(h[:, None] * off[None, :])
    return model._replace(controls=controls)


@checked
def storage_size(model: ControlPointModel) -> int:
    """Numbers stored: 2·N·3 key frames + c·(T−2)·3 controls + labels or sparse weights."""
    N = int(model.first.shape[0])
    c, T = int(model.controls.shape[0]), int(model.controls.shape[1])
    W = np.asarray(model.weights)
    hard = bool(np.all((W == 0) | (W == 1)))
    w_store = N if hard else 2 * int(np.count_nonzero(W))
    return 2 * N * 3 + c * (T - 2) * 3 + w_store


@checked
def compression_ratio(model: ControlPointModel) -> float:
    """Numbers in the dense segment (T·N·3) over the numbers the model stores."""
    N = int(model.first.shape[0])
    T = int(model.controls.shape[1])
    return T * N * 3 / storage_size(model)
