"""Fuzzy c-means with sparse memberships: each point keeps its ``p`` nearest centres.

Bezdek's alternating updates (see [`fuzzy_cmeans`][fxspace.fuzzy_cmeans]) with the membership of
point ``i`` restricted to the set ``N_p(i)`` of its ``p`` nearest centres
(truncated FCM):

    u_ik = d_ik^{-2/(m-1)} / Σ_{j ∈ N_p(i)} d_ij^{-2/(m-1)}   for k ∈ N_p(i), else 0,
    v_k  = Σ_i u_ik^m x_i / Σ_i u_ik^m.

With ``p = c`` this is exactly FCM. The far centres' memberships are tiny (they decay as
``d^{-2/(m-1)}``), so a few nearest centres carry the clustering; memory is O(n·p) instead
of O(n·c) (100 000 points × 1280 centres: 0.5 GB dense, 3 MB at p = 8), and the
``(n, c)`` distances are formed one chunk of points at a time. Cost O(n·c·d) per step.
Stops when no centre moves more than ``tol`` × the data's scale.
"""

from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from fxspace._validate import _is_tracer, check_finite, checked
from fxspace.cluster._fcm import _tiny, kmeanspp_init, squared_distances
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, check_result, result_from_flags

__all__ = ["SparseFCMResult", "sparse_fuzzy_cmeans"]


class SparseFCMResult(NamedTuple):
    """Result of [`fuzzy_cmeans`][fxspace.cluster.fuzzy_cmeans] with ``nearest``
    (truncated memberships).

    **Fields:**

    - `centers`: ``(c, d)`` centres.
    - `indices`: ``(n, p)`` int32, the ``p`` nearest centres of each point.
    - `memberships`: ``(n, p)`` memberships on those centres (rows sum to 1).
    - `objective`: ``J_m = Σ_i Σ_k u_ik^m ‖x_i − v_k‖²`` over the kept entries.
    - `num_steps`, `converged`: iterations run, and whether the centres settled
      (`converged` is `result == RESULTS.successful`).
    - `result`: a [`RESULTS`][fxspace.RESULTS] member.
    - `stats`: `max_steps`, `moved` (the last largest centre move) and `tol_abs`
      (`tol` × the data's RMS spread).
    """

    centers: Float[Array, "c d"]
    indices: Int[Array, "n p"]
    memberships: Float[Array, "n p"]
    objective: Float[Array, ""]
    num_steps: Int[Array, ""]
    result: Any
    stats: dict[str, Array]

    @property
    def converged(self):
        """``result == RESULTS.successful`` (derived, not stored)."""
        return self.result == RESULTS.successful


def _assign(x: Array, v: Array, m: float, p: int, chunk: int):
    """Nearest ``p`` centres, truncated memberships and objective, chunk by chunk."""
    n, d = x.shape
    pad = (-n) % chunk
    xp = jnp.pad(x, ((0, pad), (0, 0)))
    valid = (jnp.arange(n + pad) < n).reshape(-1, chunk)

    def one(args):
        xc, ok = args
        neg, idx = jax.lax.top_k(-squared_distances(xc, v), p)
        d2 = jnp.maximum(-neg, _tiny(x.dtype))
        w = 1.0 / d2 if m == 2.0 else jnp.power(d2, -1.0 / (m - 1.0))
        u = w / jnp.sum(w, axis=1, keepdims=True)
        um = u * u if m == 2.0 else jnp.power(u, m)
        um = jnp.where(ok[:, None], um, 0.0)
        return idx.astype(jnp.int32), jnp.where(ok[:, None], u, 0.0), jnp.sum(um * d2)

    idx, u, obj = jax.lax.map(one, (xp.reshape(-1, chunk, d), valid))
    return idx.reshape(-1, p)[:n], u.reshape(-1, p)[:n], jnp.sum(obj)


def _update_centers(x, idx, u, m, v_prev):
    """v_k = Σ u_ik^m x_i / Σ u_ik^m over the kept entries (one scatter of mass and
    weighted points together); a centre with no mass keeps its place."""
    c = v_prev.shape[0]
    um = u * u if m == 2.0 else jnp.power(u, m)
    vals = jnp.concatenate([um[..., None], um[..., None] * x[:, None, :]], axis=-1)
    tot = jax.ops.segment_sum(vals.reshape(-1, 1 + x.shape[1]), idx.reshape(-1), num_segments=c)
    mass, num = tot[:, 0], tot[:, 1:]
    ok = mass > 0
    return jnp.where(ok[:, None], num / jnp.where(ok, mass, 1.0)[:, None], v_prev)


_CAND = 16  # centres kept per point between full passes (`_loop`)


def _rank_mask(d: Array, k: int) -> Array:
    """Whether each entry of ``d`` ``(n, L)`` is among its row's ``k`` smallest (ties to
    the lower column, as `jax.lax.top_k`): one fused ``(n, L, L)`` comparison, far
    cheaper on CPU than ``top_k`` for short rows, and no gather."""
    col = jnp.arange(d.shape[1])
    before = d[:, None, :] < d[:, :, None]  # [., i, j]: entry j sorts before entry i
    before |= (d[:, None, :] == d[:, :, None]) & (col[None, None, :] < col[None, :, None])
    return jnp.sum(before, axis=2) < k


def _full_pass(x: Array, v: Array, k: int, chunk: int):
    """Each point's ``k`` nearest centres and their squared distances, ascending (every
    centre looked at, ``chunk`` points at a time)."""
    n, d = x.shape
    pad = (-n) % chunk
    xp = jnp.pad(x, ((0, pad), (0, 0)))

    def one(xc):
        neg, idx = jax.lax.top_k(-squared_distances(xc, v), k)
        return idx.astype(jnp.int32), -neg

    idx, d2 = jax.lax.map(one, xp.reshape(-1, chunk, d))
    return idx.reshape(-1, k)[:n], d2.reshape(-1, k)[:n]


@partial(jax.jit, static_argnames=("m", "p", "max_steps", "chunk"))
def _loop(x, v0, m, p, tol, max_steps, chunk):
    """Bezdek's steps with the nearest-``p`` search kept cheap and exact: a full pass
    keeps each point's ``K = 16`` nearest centres (and the K-th distance ``r_K``);
    later steps rank only those, which is exact while every point's p-th distance is
    at most ``r_K`` minus the centres' summed moves since that pass (a centre off the
    list was ≥ ``r_K`` away and has come at most that much closer); once that fails
    for any point the step runs a full pass again. The memberships live on the list
    (zero off the p nearest), so the update is Bezdek's over the p nearest."""
    scale = jnp.sqrt(jnp.mean(jnp.sum(jnp.square(x - jnp.mean(x, axis=0, keepdims=True)), axis=1)))
    c = v0.shape[0]
    k = min(_CAND, c)
    n = x.shape[0]
    top = jnp.arange(k) < p

    def full(v):
        cand, d2 = _full_pass(x, v, k, chunk)
        reach = jnp.sqrt(d2[:, -1]) if k < c else jnp.full((n,), jnp.inf, x.dtype)
        return cand, d2, jnp.broadcast_to(top, cand.shape), reach, jnp.zeros((), x.dtype)

    def step(v, cand, reach, drift):
        d2 = jnp.sum(jnp.square(v[cand] - x[:, None, :]), axis=-1)
        keep = _rank_mask(d2, p)
        pth = jnp.sqrt(jnp.max(jnp.where(keep, d2, -jnp.inf), axis=1))
        exact = jnp.all(pth <= reach - drift)
        return jax.lax.cond(exact, lambda: (cand, d2, keep, reach, drift), lambda: full(v))

    def cond(s):
        return (s[1] < max_steps) & (s[2] >= tol * scale)

    def body(s):
        v, step_no, _, cand, reach, drift = s
        cand, d2, keep, reach, drift = step(v, cand, reach, drift)
        d2 = jnp.maximum(d2, _tiny(x.dtype))
        w = jnp.where(keep, 1.0 / d2 if m == 2.0 else jnp.power(d2, -1.0 / (m - 1.0)), 0.0)
        new = _update_centers(x, cand, w / jnp.sum(w, axis=1, keepdims=True), m, v)
        moved = jnp.max(jnp.sqrt(jnp.sum(jnp.square(new - v), axis=1)))
        return new, step_no + 1, moved, cand, reach, drift + moved

    cand0, _, _, reach0, _ = full(v0)
    init = (v0, jnp.int32(0), jnp.asarray(jnp.inf, x.dtype), cand0, reach0, jnp.zeros((), x.dtype))
    v, steps, moved, _, _, _ = jax.lax.while_loop(cond, body, init)
    idx, u, obj = _assign(x, v, m, p, chunk)
    ok = jnp.isfinite(obj) & jnp.all(jnp.isfinite(v))
    bad_in = ~(jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(v0)))
    result = result_from_flags(
        converged=(moved < tol * scale) & ok, nonfinite_input=bad_in, nonfinite_output=~ok
    )
    stats = {
        "max_steps": jnp.asarray(max_steps, jnp.int32),
        "moved": moved,
        "tol_abs": tol * scale,
    }
    v, u, obj = (jnp.where(bad_in, jnp.nan, a) for a in (v, u, obj))
    return SparseFCMResult(v, idx, u, obj, steps, result, stats)


@checked
def sparse_fuzzy_cmeans(
    x: Float[Array, "n d"],
    n_clusters: int,
    m: float = 2.0,
    *,
    nearest: int = 8,
    key: Array | None = None,
    init_centers: Float[Array, "c d"] | None = None,
    tol: float = 1e-4,
    max_steps: int = 300,
    chunk: int = 8192,
    throw: bool = False,
) -> SparseFCMResult:
    """Fuzzy c-means whose memberships keep each point's `nearest` centres (memory O(n·p)).

    **Arguments:**

    - `x`: ``(n_samples, n_features)`` data.
    - `n_clusters`: centres c; `m`: fuzzifier > 1.
    - `nearest`: centres kept per point, p ≤ c (p = c is plain FCM).
    - `key`: k-means++ seeding key, or `init_centers` ``(c, d)`` to warm-start.
    - `tol`: stop when no centre moves more than ``tol`` × RMS spread of the data.
    - `max_steps`: iteration cap; `chunk`: points per block of the distance pass.
    - `throw`: raise [`FxspaceError`][fxspace.FxspaceError] unless the result is
      `RESULTS.successful` (under `jit` through `equinox.error_if`).

    **Returns:** [`SparseFCMResult`][fxspace.cluster.SparseFCMResult] with `.result`,
    `.num_steps`, `.stats`; NaN/inf input gives `RESULTS.nonfinite_input`.

    **Example:**

    ```python
    res = fx.cluster.fuzzy_cmeans(Y, 640, nearest=8, key=jax.random.key(0))
    ```
    """
    x, c, p, v0 = _prepare(x, n_clusters, m, nearest, key, init_centers, throw)
    res = _loop(
        x, v0, float(m), p, jnp.asarray(tol, x.dtype), int(max_steps), min(int(chunk), x.shape[0])
    )
    return check_result(res.result, throw, "fuzzy_cmeans", res)


def _prepare(x, n_clusters, m, nearest, key, init_centers, throw):
    """``(x, c, p, v0)`` checked (errors name the argument), with the k-means++ seeds."""
    x = jnp.asarray(x)
    if x.ndim != 2 or x.shape[0] < 1:
        raise FxspaceError(f"x must be (n_samples, n_features), got shape {x.shape}")
    if throw and not _is_tracer(x):
        check_finite(x, "x")
    n = x.shape[0]
    c = int(n_clusters)
    if not 1 <= c <= n:
        raise FxspaceError(f"n_clusters must be in [1, n_samples = {n}], got {n_clusters}")
    if not m > 1:
        raise FxspaceError(f"m (fuzzifier) must be > 1, got {m}")
    p = min(int(nearest), c)
    if p < 1:
        raise FxspaceError(f"nearest must be >= 1, got {nearest}")
    if init_centers is not None:
        v0 = jnp.asarray(init_centers, x.dtype)
        if v0.shape != (c, x.shape[1]):
            raise FxspaceError(f"init_centers must be ({c}, {x.shape[1]}), got {v0.shape}")
    elif key is None:
        raise FxspaceError("pass key (k-means++ seeding) or init_centers")
    else:
        v0 = kmeanspp_init(x, c, key)
    return x, c, p, v0
