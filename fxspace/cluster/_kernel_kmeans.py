"""Gaussian-kernel k-means (Dhillon, Guan & Kulis 2004) as a jitted fixed point.

Points are clustered in the feature space of ``k(x, y) = exp(−γ‖x − y‖²)``. With hard
labels and ``H`` the one-hot label matrix, the squared feature-space distance of point
``i`` to the centre of cluster ``c`` is

    d(i, c) = K_ii − 2 (K H)_ic / n_c + (Hᵀ K H)_cc / n_c²,

and Lloyd's step assigns every point to its nearest centre. Each step is one matrix
product ``K H`` — with ``n_init`` restarts batched into one ``K @ [H_1 … H_R]`` — so the
cost is O(n² · c · n_init) flops per step and the memory O(n²) for the Gram matrix.
"""

from __future__ import annotations

import math
import os
from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from fxspace._validate import (
    _is_tracer,
    as_float_array,
    check_finite,
    check_int,
    check_scalar,
    check_scale,
    checked,
)
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, check_result, result_from_flags

__all__ = [
    "KernelKMeansResult",
    "kernel_kmeans",
    "kernel_kmeans_gram",
    "gaussian_kernel",
    "median_gamma",
    "kernel_kmeans_memory",
]


class KernelKMeansResult(NamedTuple):
    """Result of [`kernel_kmeans`][fxspace.kernel_kmeans] (the best of ``n_init`` restarts
    by objective).

    **Fields:**

    - `labels`: ``(n,)`` cluster of each point (``-1`` everywhere when the input holds
      NaN/inf).
    - `objective`: Σ_i d(i, label_i), the within-cluster feature-space sum of squares.
    - `num_steps`: Lloyd steps run (all restarts advance together).
    - `converged`: the best restart's labels stopped changing before ``max_steps``
      (`result == RESULTS.successful`).
    - `medoids`: ``(c,)`` index of the point nearest (in feature space) to each centre;
      ``-1`` for an empty cluster.
    - `sizes`: ``(c,)`` points per cluster.
    - `restart_objectives`: ``(n_init,)`` objective of every restart.
    - `result`: a [`RESULTS`][fxspace.RESULTS] member (`successful`,
      `max_steps_reached`, `nonfinite_input` for NaN/inf in the points or the Gram
      matrix, `nonfinite_output`).
    - `stats`: `max_steps` and `n_unsettled` (restarts whose labels still changed).
    """

    labels: Int[Array, " n"]
    objective: Float[Array, ""]
    num_steps: Int[Array, ""]
    medoids: Int[Array, " c"]
    sizes: Int[Array, " c"]
    restart_objectives: Float[Array, " n_init"]
    result: Any
    stats: dict[str, Array]

    @property
    def converged(self):
        """``result == RESULTS.successful`` (derived, not stored)."""
        return self.result == RESULTS.successful


@checked
def gaussian_kernel(
    X: Float[ArrayLike, "n d"], gamma: float | Float[Array, ""]
) -> Float[Array, "n n"]:
    """Gram matrix ``K_ij = exp(−γ ‖x_i − x_j‖²)`` (O(n²) memory)."""
    X = jnp.asarray(X)
    sq = jnp.sum(X * X, axis=1)
    d2 = jnp.maximum(sq[:, None] + sq[None, :] - 2.0 * (X @ X.T), 0.0)
    return jnp.exp(-gamma * d2)


@checked
def median_gamma(X: Float[ArrayLike, "n d"], max_points: int = 1000) -> Float[Array, ""]:
    """Median heuristic ``γ = 1 / median ‖x_i − x_j‖²`` (≤ ``max_points`` evenly spaced points)."""
    if max_points < 2:
        raise FxspaceError(f"max_points must be >= 2 (a median needs a pair), got {max_points}")
    X = as_float_array(X, "X", ndim=2, min_frames=2)
    step = max(1, X.shape[0] // max_points)
    S = X[::step]
    # scaled before squaring, so float32 points at 1e-25 or 1e19 neither underflow nor overflow
    scale = jnp.max(jnp.abs(S))
    scale = jnp.where(scale > 0, scale, 1.0)
    S = S / scale
    sq = jnp.sum(S * S, axis=1)
    d2 = jnp.maximum(sq[:, None] + sq[None, :] - 2.0 * (S @ S.T), 0.0)
    iu = jnp.triu_indices(S.shape[0], 1)
    med = jnp.median(d2[iu])
    gamma = jnp.where(med > 0, 1.0 / jnp.where(med > 0, med, 1.0) / scale**2, 1.0)
    if not _is_tracer(gamma) and not bool(jnp.isfinite(gamma)):
        raise FxspaceError(
            f"median_gamma: the median squared distance of X ({float(med):g} x {float(scale):g}²) "
            f"is out of the {X.dtype} range; rescale X (or pass gamma explicitly)"
        )
    return gamma


def kernel_kmeans_memory(n: int, n_clusters: int, n_init: int, itemsize: int = 8) -> int:
    """Bytes [`kernel_kmeans`][fxspace.kernel_kmeans] needs: the Gram matrix plus the
    batched label products."""
    return itemsize * (2 * n * n + 4 * n * n_clusters * n_init)


def _default_limit() -> int:
    try:
        phys = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        phys = 8 * 2**30
    return int(0.5 * phys)


def _plusplus(K: Float[Array, "n n"], c: int, key: PRNGKeyArray) -> Int[Array, " n"]:
    """k-means++ seeding in feature space; returns the initial labels."""
    n = K.shape[0]
    diag = jnp.diag(K)
    k0, key = jax.random.split(key)
    first = jax.random.randint(k0, (), 0, n)
    centres = jnp.zeros((c,), jnp.int32).at[0].set(first.astype(jnp.int32))
    mind = diag + diag[first] - 2.0 * K[:, first]

    def body(j, carry):
        centres, mind, key = carry
        key, sub = jax.random.split(key)
        p = jnp.maximum(mind, 0.0)
        p = jnp.where(jnp.sum(p) > 0, p, jnp.ones_like(p))
        nxt = jax.random.choice(sub, n, p=p / jnp.sum(p))
        d = diag + diag[nxt] - 2.0 * K[:, nxt]
        return centres.at[j].set(nxt.astype(jnp.int32)), jnp.minimum(mind, d), key

    centres, _, _ = lax.fori_loop(1, c, body, (centres, mind, key))
    dist = diag[centres][None, :] - 2.0 * K[:, centres]
    return (
        jnp.argmin(dist, axis=1).astype(jnp.int32).at[centres].set(jnp.arange(c, dtype=jnp.int32))
    )


def _kh_full(K, labels, c):
    """``K H`` for every restart: (R, n, c), one (n × n)·(n × R·c) product."""
    R, n = labels.shape
    H = jax.nn.one_hot(labels, c, dtype=K.dtype)  # (R, n, c)
    KH = (K @ jnp.moveaxis(H, 0, 1).reshape(n, R * c)).reshape(n, R, c)
    return jnp.moveaxis(KH, 1, 0)


def _kh_update(K, KH, old, new, c, budget):
    """``K H_new = K H_old + K[:, moved] (H_new − H_old)[moved]`` with ≤ ``budget`` moves."""
    n = K.shape[0]
    moved = old != new  # (R, n)
    idx = jax.vmap(lambda m: jnp.nonzero(m, size=budget, fill_value=n)[0])(moved)  # (R, B)
    Kp = jnp.concatenate([K, jnp.zeros((n, 1), K.dtype)], axis=1)  # column n = 0
    cols = Kp[:, idx]  # (n, R, B)
    oldp = jnp.concatenate([old, jnp.zeros_like(old[:, :1])], axis=1)
    newp = jnp.concatenate([new, jnp.zeros_like(new[:, :1])], axis=1)
    g_old = jnp.take_along_axis(oldp, idx, axis=1)
    g_new = jnp.take_along_axis(newp, idx, axis=1)
    delta = jax.nn.one_hot(g_new, c, dtype=K.dtype) - jax.nn.one_hot(g_old, c, dtype=K.dtype)
    return KH + jnp.einsum("nrb,rbc->rnc", cols, delta)


def _distances(diag, labels, KH, c):
    """Feature-space distances d(i, c) (R, n, c) and cluster sizes (R, c)."""
    H = jax.nn.one_hot(labels, c, dtype=KH.dtype)  # (R, n, c)
    sizes = jnp.sum(H, axis=1)  # (R, c)
    s = jnp.sum(H * KH, axis=1)  # (R, c): Σ_{j,l ∈ c} K_jl
    safe = jnp.where(sizes > 0, sizes, 1.0)
    d = diag[None, :, None] - 2.0 * KH / safe[:, None, :] + (s / safe**2)[:, None, :]
    return jnp.where(sizes[:, None, :] > 0, d, jnp.inf), sizes


def _reseed_empty(labels, mind, c):
    """Give every empty cluster the point farthest from its centre (``mind``), per restart."""
    n = labels.shape[0]
    sizes = jnp.zeros((c,), jnp.int32).at[labels].add(1)
    empty = sizes == 0
    _, far = lax.top_k(mind, c)
    rank = jnp.cumsum(empty) - 1
    target = jnp.where(empty, far[jnp.clip(rank, 0, c - 1)], n)
    return labels.at[target].set(jnp.arange(c, dtype=labels.dtype), mode="drop")


@checked
def kernel_kmeans_gram(
    K: Float[ArrayLike, "n n"],
    n_clusters: int,
    *,
    key: PRNGKeyArray | None = None,
    n_init: int = 20,
    max_steps: int = 100,
    init: Literal["k-means++", "random"] | Int[ArrayLike, "n_init n"] = "k-means++",
    throw: bool = False,
) -> KernelKMeansResult:
    """Kernel k-means on a precomputed Gram matrix ``K`` (see
    [`kernel_kmeans`][fxspace.kernel_kmeans]; `throw` as there)."""
    K = as_float_array(K, "K", ndim=2, finite="allow")
    if throw and not _is_tracer(K):
        check_finite(K, "K")  # names where the NaN/inf are
    if K.shape[0] != K.shape[1]:
        raise FxspaceError(f"K must be a square (n, n) Gram matrix; got shape {K.shape}")
    if not isinstance(n_clusters, int | np.integer) or not 1 <= n_clusters <= K.shape[0]:
        raise FxspaceError(
            f"n_clusters must be an int in [1, n_points={K.shape[0]}]; got {n_clusters!r}"
        )
    check_int(max_steps, "max_steps", low=0)
    if key is None:
        key = jax.random.PRNGKey(0)
    if isinstance(init, str):
        labels0 = None
        mode = init
    else:
        lab = np.asarray(init)
        if lab.dtype.kind not in "iu" or lab.size == 0 or lab.size % K.shape[0]:
            raise FxspaceError(
                f"init labels must be integers of shape (n_init, n={K.shape[0]}); got "
                f"{lab.dtype} of shape {lab.shape}"
            )
        if lab.min() < 0 or lab.max() >= n_clusters:
            raise FxspaceError(
                f"init labels must lie in [0, n_clusters - 1 = {n_clusters - 1}]; got values "
                f"from {lab.min()} to {lab.max()}"
            )
        labels0 = jnp.asarray(lab, jnp.int32).reshape(-1, K.shape[0])
        n_init = labels0.shape[0]
        mode = "labels"
    res = _kkm_core(K, int(n_clusters), key, int(n_init), int(max_steps), mode, labels0)
    return check_result(res.result, throw, "kernel_kmeans", res)


@partial(jax.jit, static_argnums=(1, 3, 4, 5))
def _kkm_core(K, n_clusters, key, n_init, max_steps, init, labels0):
    K = jnp.asarray(K)
    n = K.shape[0]
    c = int(n_clusters)
    diag = jnp.diag(K)
    if init != "labels":
        keys = jax.random.split(key, n_init)
        if init == "k-means++":
            labels0 = jax.vmap(lambda k: _plusplus(K, c, k))(keys)
        else:
            labels0 = jax.vmap(lambda k: jax.random.randint(k, (n,), 0, c))(keys).astype(jnp.int32)

    budget = max(8, min(n, n // 16))
    bad_in = ~jnp.all(jnp.isfinite(K))  # no Lloyd steps on garbage

    def cond(s):
        _, _, changed, it = s
        return jnp.any(changed) & (it < max_steps) & ~bad_in

    def body(s):
        labels, KH, _, it = s
        d, _ = _distances(diag, labels, KH, c)
        new = jnp.argmin(d, axis=2).astype(jnp.int32)
        new = jax.vmap(_reseed_empty, (0, 0, None))(new, jnp.min(d, axis=2), c)
        n_moved = jnp.max(jnp.sum(new != labels, axis=1))
        # few points move after the first steps: update K H by their columns only
        KH = lax.cond(
            n_moved <= budget,
            lambda: _kh_update(K, KH, labels, new, c, budget),
            lambda: _kh_full(K, new, c),
        )
        return new, KH, jnp.any(new != labels, axis=1), it + 1

    R = labels0.shape[0]
    labels, _, changed, steps = lax.while_loop(
        cond, body, (labels0, _kh_full(K, labels0, c), jnp.ones((R,), bool), jnp.int32(0))
    )
    d, sizes = _distances(diag, labels, _kh_full(K, labels, c), c)  # exact final objective
    point_d = jnp.take_along_axis(d, labels[:, :, None], axis=2)[:, :, 0]
    objs = jnp.sum(point_d, axis=1)
    best = jnp.argmin(objs)
    lab = labels[best]
    pd = point_d[best]
    member = jax.nn.one_hot(lab, c, dtype=bool)
    med = jnp.argmin(jnp.where(member, pd[:, None], jnp.inf), axis=0).astype(jnp.int32)
    sz = sizes[best].astype(jnp.int32)
    med = jnp.where(sz > 0, med, -1)
    # NaN/inf in K (e.g. a NaN point or a bad γ under jit) never reports convergence
    ok = jnp.isfinite(objs[best])
    result = result_from_flags(
        converged=~changed[best] & ok, nonfinite_input=bad_in, nonfinite_output=~ok
    )
    lab = jnp.where(bad_in, -1, lab)
    med = jnp.where(bad_in, -1, med)
    stats = {
        "max_steps": jnp.asarray(max_steps, jnp.int32),
        "n_unsettled": jnp.sum(changed).astype(jnp.int32),
    }
    return KernelKMeansResult(lab, objs[best], steps, med, sz, objs, result, stats)


@checked
def kernel_kmeans(
    X: Float[ArrayLike, "n d"],
    n_clusters: int,
    gamma: float | Float[ArrayLike, ""] | None = None,
    *,
    key: PRNGKeyArray | None = None,
    n_init: int = 20,
    max_steps: int = 100,
    init: Literal["k-means++", "random"] | Int[ArrayLike, "n_init n"] = "k-means++",
    memory_limit_bytes: int | None = None,
    throw: bool = False,
) -> KernelKMeansResult:
    """Gaussian-kernel k-means, ``n_init`` restarts batched, the best by objective.

    Minimises ``Σ_i ‖φ(x_i) − μ_{label_i}‖²`` in the feature space of
    ``k(x, y) = exp(−γ‖x − y‖²)`` by Lloyd's fixed point in a ``lax.while_loop``; restarts
    are seeded by k-means++ in feature space (``init``) and advance together as one
    batched matrix product. Empty clusters are re-seeded with the farthest point.

    **Memory: O(n²)** — the ``n × n`` Gram matrix (plus O(n·c·n_init)); the call refuses,
    with the estimate, inputs that would need more than ``memory_limit_bytes`` (default:
    half the physical memory). Time: O(n²·c·n_init) per step.

    **Arguments:**

    - `X`: ``(n, d)`` points (e.g. vertex trajectories flattened to ``d = 3T``).
    - `n_clusters`: c, static.
    - `gamma`: kernel width γ > 0; ``None`` → median heuristic
      ([`median_gamma`][fxspace.median_gamma]).
    - `key`: PRNG key for the seeding; `n_init`: restarts (the paper used 20).
    - `max_steps`: bound on Lloyd steps. `init`: ``"k-means++"``, ``"random"`` or
      initial labels ``(n_init, n)``.
    - `memory_limit_bytes`: refuse inputs whose Gram matrix would need more.
    - `throw`: raise [`FxspaceError`][fxspace.FxspaceError] unless the result is
      `RESULTS.successful` (NaN/inf in `X` is named by position before any work; under
      `jit` the check runs through `equinox.error_if`).

    **Returns:** [`KernelKMeansResult`][fxspace.KernelKMeansResult] with `.result`,
    `.num_steps` and `.stats`; NaN/inf in `X` gives `RESULTS.nonfinite_input` and labels
    of ``-1``, never a plausible partition.

    **Example:**

    ```python
    import jax
    import numpy as np
    import fxspace as fx

    rng = np.random.default_rng(0)
    X = np.concatenate([rng.normal(size=(50, 2)), rng.normal(size=(50, 2)) + 6])
    res = fx.kernel_kmeans(X, 2, gamma=0.5, key=jax.random.key(0), n_init=4)
    assert res.result == fx.RESULTS.successful
    ```
    """
    X = as_float_array(X, "X", axes=("n_points", "n_features"), finite="allow")
    check_scale(X, "X")  # squared distances overflowing to inf: refuse, never "converged"
    if throw and not _is_tracer(X):
        check_finite(X, "X")  # names where the NaN/inf are
    n = X.shape[0]
    if not isinstance(n_clusters, int | np.integer) or not 1 <= n_clusters <= n:
        raise FxspaceError(f"n_clusters must be an int in [1, n_points={n}]; got {n_clusters!r}")
    if n_init < 1:
        raise FxspaceError(f"n_init must be >= 1; got {n_init}")
    if isinstance(init, str) and init not in ("k-means++", "random"):
        raise FxspaceError(f"init must be 'k-means++', 'random' or labels; got {init!r}")
    if not isinstance(init, str):
        n_init = int(np.prod(np.shape(init)) // n)
    if gamma is not None:
        gamma = check_scalar(gamma, "gamma", low=0.0, low_open=True)
    need = kernel_kmeans_memory(n, int(n_clusters), n_init, X.dtype.itemsize)
    if memory_limit_bytes is None:
        limit = _default_limit()
    else:
        limit = check_int(memory_limit_bytes, "memory_limit_bytes", low=1)
    if need > limit:
        n_fit = int(math.sqrt(limit / (2 * X.dtype.itemsize)))
        raise FxspaceError(
            f"kernel_kmeans on n={n} points needs about {need / 2**30:.2f} GiB (the n×n Gram "
            f"matrix is O(n²)), more than the limit of {limit / 2**30:.2f} GiB "
            f"(memory_limit_bytes); subsample to about {n_fit} points, use float32 inputs, "
            "or raise memory_limit_bytes"
        )
    if gamma is None:
        gamma = median_gamma(X)
    K = gaussian_kernel(X, gamma)
    return kernel_kmeans_gram(
        K, int(n_clusters), key=key, n_init=n_init, max_steps=max_steps, init=init, throw=throw
    )
