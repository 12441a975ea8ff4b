"""The hierarchy of fuzzy c-means levels over the 2-D expression space (Kim & Jung §3–4),
at every size.

Level l has c_l = c0·2^l centres (c0 ≈ 10), up to the level that shows every frame
(c_L = T); each centre is shown as its nearest frame. Level l+1 is warm-started from
level l by *splitting* centres (LBG-style): the centres that contribute most to the
objective are replaced by two children at v ± 0.8 σ r, r the principal axis of the
cluster's covariance (over the frames it wins) and σ² its variance along r.

The options sit on solver objects (optimistix style): the FCM is `FuzzyCMeans` (full
memberships, ~10³ frames) or `TruncatedFuzzyCMeans` (each frame's nearest centres, 10⁵
frames and more), the links a `LinkRule`; the frames' *paths* are their `Geodesics` or
their `NeighbourGraph` (`fxspace.expression.Paths`), whichever the space holds.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from types import SimpleNamespace
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_int, check_scalar, checked
from fxspace.cluster import (
    SparseFCMResult,
    fuzzy_cmeans,
    kmeanspp_extend,
    kmeanspp_init,
    pad_rows,
)
from fxspace.errors import FxspaceError
from fxspace.navigation._level import Hierarchy, Level, level_sizes, pair_csr
from fxspace.navigation._links import LinkRule, default_link_radius, level_links
from fxspace.navigation._rho import _link_all, _Linker
from fxspace.navigation._solvers import FuzzyCMeans, TruncatedFuzzyCMeans
from fxspace.results import RESULTS

__all__ = [
    "FuzzyCMeans",
    "TruncatedFuzzyCMeans",
    "build_hierarchy",
    "cold_levels",
    "finest_level",
    "frame_links",
    "nearest_frames",
    "relink",
    "split_centers",
]


def _hard(fit, m: float):
    """Each frame's hard cluster and its membership^m (full or truncated memberships);
    full ones padded with zero columns to `pad_rows` up to 2^23 entries (a shared compile;
    a zero is never the largest of a row that sums to 1)."""
    u, idx = fit.memberships, getattr(fit, "indices", None)
    if idx is None and not isinstance(u, jax.core.Tracer):
        u = np.asarray(u)
        if u.shape[0] * pad_rows(u.shape[1]) <= 1 << 23:
            u = np.concatenate([u, np.zeros((u.shape[0], pad_rows(u.shape[1]) - u.shape[1]),
                                            u.dtype)], axis=1)  # fmt: skip
    return _hard_arrays(jnp.asarray(u), idx, m)


@partial(jax.jit, static_argnames=("m",))
def _hard_arrays(u, idx, m: float):
    k = jnp.argmax(u, axis=1)
    w = jnp.power(jnp.take_along_axis(u, k[:, None], axis=1)[:, 0], m)
    lab = k if idx is None else jnp.take_along_axis(jnp.asarray(idx), k[:, None], axis=1)[:, 0]
    return lab.astype(jnp.int32), w


def _split(x, centers, lab, w, n_new: int, alpha=0.8, power_steps: int = 8):
    """The split of `split_centers`: the ``n_new`` centres with the largest share of the
    objective, each replaced by two children (`_split_dirs`, with the centres padded to
    `pad_rows` rows, so that the levels share a few compiles)."""
    c = centers.shape[0]
    size = pad_rows(c)
    traced = any(isinstance(a, jax.core.Tracer) for a in (x, centers, lab, w))
    xp = jnp if traced else np
    cp = xp.concatenate([xp.asarray(centers), xp.zeros((size - c, centers.shape[1]),
                                                        centers.dtype)])  # fmt: skip
    parent, children = _split_dirs(x, cp, lab, w, jnp.asarray(n_new), alpha, power_steps)
    parent, children = xp.asarray(parent)[:c], xp.asarray(children)[:n_new]
    return jnp.asarray(xp.concatenate([parent, children], axis=0))


@partial(jax.jit, static_argnames=("power_steps",))
def _split_dirs(x, centers, lab, w, n_new, alpha, power_steps: int):
    """``(parents, children)`` ``(c, d)``: the ``n_new`` centres with the largest share of
    the objective moved by ``−α σ r`` (``r`` the principal axis of the frames each wins,
    by power iteration; σ² the variance along it), and their children at ``+α σ r`` first
    in that order (the rest: padding). Rows of ``centers`` that no frame wins have a zero
    share and stay."""
    # FCM's memberships have heavy tails (u ~ d^-2), which inflate a fuzzy covariance;
    # the split uses the frames each centre wins, weighted by u^m
    c = centers.shape[0]
    mass = jnp.maximum(jax.ops.segment_sum(w, lab, c), jnp.finfo(x.dtype).tiny)
    dx = x - centers[lab]
    contribution = jax.ops.segment_sum(w * jnp.sum(dx * dx, axis=1), lab, c)
    order = jnp.argsort(-contribution)
    r0 = jnp.ones_like(centers) / jnp.sqrt(centers.shape[1])
    r0 = r0.at[:, 0].add(0.1)

    def cov_times(r):  # C_k r = Σ_i w_i (x_i − v_k)((x_i − v_k)·r) / Σ_i w_i over k's frames
        proj = jnp.sum(dx * r[lab], axis=1)
        return jax.ops.segment_sum((w * proj)[:, None] * dx, lab, c) / mass[:, None]

    def step(r, _):
        cr = cov_times(r)
        nrm = jnp.linalg.norm(cr, axis=1, keepdims=True)
        return jnp.where(nrm > 0, cr / jnp.where(nrm > 0, nrm, 1.0), r), None

    r, _ = jax.lax.scan(step, r0 / jnp.linalg.norm(r0, axis=1, keepdims=True), None, power_steps)
    lam = jnp.maximum(jnp.sum(r * cov_times(r), axis=1), 0.0)
    d = alpha * jnp.sqrt(lam)[:, None] * r
    split = jnp.zeros(c, bool).at[order].set(jnp.arange(c) < n_new)
    return jnp.where(split[:, None], centers - d, centers), (centers + d)[order]


def split_centers(
    x: Float[Array, "n d"],
    centers: Float[Array, "c d"],
    memberships,
    n_clusters: int,
    m: float = 2.0,
) -> Float[Array, "c2 d"]:
    """Initial centres for a finer level: the ``n_clusters − c`` centres with the largest
    share of the objective are each replaced by two children at v ± 0.8 σ r (r: principal
    axis of the covariance of the frames the cluster wins, by power iteration; σ²: the
    variance along r). ``memberships``: ``(n, c)``, or an FCM record (full or truncated)."""
    x = as_float_array(x, "x", ndim=2)
    centers = as_float_array(centers, "centers", shape=(None, x.shape[1]))
    c = centers.shape[0]
    n_clusters = check_int(n_clusters, "n_clusters")
    m = check_scalar(m, "m", low=1.0, low_open=True)
    if not c <= n_clusters <= 2 * c:
        raise FxspaceError(
            f"n_clusters must lie in [{c}, {2 * c}] to split {c} centres, got {n_clusters}"
        )
    if n_clusters == c:
        return jnp.asarray(centers)
    if hasattr(memberships, "memberships"):
        fit = memberships
    else:
        u = as_float_array(memberships, "memberships", shape=(x.shape[0], c))
        fit = SimpleNamespace(memberships=u)
    lab, w = _hard(fit, float(m))
    return _split(jnp.asarray(x), jnp.asarray(centers), lab, w.astype(x.dtype), n_clusters - c)


def nearest_frames(embedding: Float[Array, "T d"], centers: Float[Array, "c d"]) -> np.ndarray:
    """(c,) index of the frame nearest each centre (how each centre is shown)."""
    from scipy.spatial import cKDTree

    embedding = np.asarray(as_float_array(embedding, "embedding", ndim=2), np.float64)
    centers = as_float_array(centers, "centers", shape=(None, embedding.shape[1]))
    return cKDTree(embedding).query(np.asarray(centers, np.float64), k=1)[1].astype(np.int64)


def _starts(x, c, prev, k_cold, k_ext, fcm: FuzzyCMeans) -> list:
    """The FCM starts of one level: k-means++ seeds (first level or cold), else the split
    of the coarser centres + k-means++-extend draws."""
    if prev is None or not fcm.warm_start:
        n_seeds = max(1 + fcm.restarts, fcm.first_level_seeds if prev is None else 1)
        return [kmeanspp_init(x, c, k) for k in jax.random.split(k_cold, n_seeds)]
    n_new = c - prev.centers.shape[0]
    starts = [split_centers(x, prev.centers, prev, c, fcm.m)] if fcm.split else []
    return starts + [
        kmeanspp_extend(x, prev.centers, n_new, k) for k in jax.random.split(k_ext, fcm.restarts)
    ]


def _frames_fit(x):
    """The FCM record of the level where every frame is a centre: the fixed point (each
    frame its own centre, membership 1, J = 0)."""
    T = x.shape[0]
    return SparseFCMResult(
        np.asarray(x), np.arange(T, dtype=np.int32)[:, None], np.ones((T, 1), np.float32),
        np.asarray(0.0), np.asarray(0), RESULTS.successful,
        {"max_steps": np.asarray(0), "moved": np.asarray(0.0), "tol_abs": np.asarray(0.0)},
    )  # fmt: skip


def _fcm_levels(x, sizes, T, key, fcm: FuzzyCMeans) -> Iterator[Level]:
    """The levels (no links yet), one at a time: each size's FCM from its starts, the
    lowest objective."""
    prev = None
    for c in sizes:
        key, k_cold, k_ext = jax.random.split(key, 3)
        if c == T:
            yield Level(T, np.asarray(x), np.arange(T, dtype=np.int64), _frames_fit(x),
                        stats={"init": "frames", "num_steps_split": -1,
                               "total_steps": 0})  # fmt: skip
            continue
        inits = _starts(x, c, prev, k_cold, k_ext, fcm)
        # the starts run one after another: on CPU a vmapped while-loop costs more than the
        # sum of the single runs (every lane pays for the slowest)
        runs = [jax.block_until_ready(fcm.run(x, c, v)) for v in inits]
        objs = np.asarray([float(r.objective) for r in runs])
        best = int(np.argmin(np.where(np.isnan(objs), np.inf, objs)))
        res = runs[best]
        warm = prev is not None and fcm.warm_start
        init = ("kmeans++" if not warm else
                "split" if (fcm.split and best == 0) else "kmeans++-extend")  # fmt: skip
        stats = {"init": init,
                 "num_steps_split": int(runs[0].num_steps) if warm and fcm.split else -1,
                 "total_steps": int(sum(int(r.num_steps) for r in runs))}  # fmt: skip
        centers = np.asarray(res.centers)
        yield Level(c, centers, nearest_frames(x, centers), res, stats=stats)
        prev = res


_FCM_KEYS = ("m", "tol", "max_steps", "criterion", "warm_start", "restarts", "split",
             "first_level_seeds")  # fmt: skip


def _options(fcm, links, old: dict[str, Any]) -> tuple[FuzzyCMeans, LinkRule | None]:
    """The solver objects, with the deprecated keywords of `build_hierarchy` mapped onto
    them (``nearest`` → `TruncatedFuzzyCMeans`; ``rho_scale``, ``bridges``,
    ``max_link_centres``, ``link_sweep_max_centres`` → `LinkRule`)."""
    nearest = old.pop("nearest", None)
    if fcm is None:
        fcm = FuzzyCMeans() if nearest is None else TruncatedFuzzyCMeans(nearest=int(nearest))
    elif nearest is not None:
        fcm = dataclasses.replace(fcm, nearest=int(nearest)) if hasattr(fcm, "nearest") else (
            TruncatedFuzzyCMeans(**{f.name: getattr(fcm, f.name)
                                    for f in dataclasses.fields(fcm)}, nearest=int(nearest)))
    if not isinstance(fcm, FuzzyCMeans):
        raise FxspaceError(
            f"fcm must be FuzzyCMeans(...) or TruncatedFuzzyCMeans(...), got {type(fcm).__name__}"
        )
    fk = {k: old.pop(k) for k in _FCM_KEYS if k in old}
    if fk:
        fcm = dataclasses.replace(fcm, **fk)
    if links is False:
        return fcm, None
    rule = LinkRule() if links is None or links is True else links
    if not isinstance(rule, LinkRule):
        raise FxspaceError(f"links must be a LinkRule(...) (or False), got {type(links).__name__}")
    lk = {"rho": old.pop("rho_scale", rule.rho), "bridges": old.pop("bridges", rule.bridges),
          "sweep_max_centres": old.pop("link_sweep_max_centres", rule.sweep_max_centres),
          "max_centres": old.pop("max_link_centres", rule.max_centres)}  # fmt: skip
    if old:
        raise FxspaceError(f"build_hierarchy: unknown option(s) {sorted(old)}")
    return fcm, dataclasses.replace(rule, **lk)


@checked
def build_hierarchy(
    embedding: Float[Array, "T d"],
    paths=None,
    *,
    c0: int = 10,
    key: Array | None = None,
    fcm: FuzzyCMeans | None = None,
    links: LinkRule | bool | None = None,
    levels: int | None = None,
    finest: bool = True,
    **deprecated,
) -> Hierarchy:
    """Fuzzy c-means levels c0·2^l over the expression-space ``embedding`` and their links
    (Kim & Jung §3–4), at any size.

    **Arguments:**

    - `embedding`: ``(T, 2)`` MDS coordinates.
    - `paths`: the frames' ``Geodesics`` or `NeighbourGraph` (`fxspace.expression.Paths`;
      None: no links).
    - `c0`: centres at the coarsest level; `key`: PRNG key of the k-means++ draws.
    - `fcm`: `FuzzyCMeans(...)` (default) or `TruncatedFuzzyCMeans(nearest=8)` (memory
      O(T·p), for 10⁵ frames and more).
    - `links`: a `LinkRule` (default `LinkRule()`: ρ by the paper's experiment, no
      bridges); False: no links.
    - `levels`: the FCM levels c0, 2c0, … (default: every one below T); `finest`: also
      the level where every frame is a centre (default True).
    - Deprecated keywords, mapped onto the objects: ``m``, ``tol``, ``max_steps``,
      ``criterion``, ``warm_start``, ``restarts``, ``split``, ``first_level_seeds``,
      ``nearest`` (the FCM); ``rho_scale``, ``bridges``, ``max_link_centres``,
      ``link_sweep_max_centres`` (the `LinkRule`).

    **Returns:** a `Hierarchy`; every level's `Level.fit.result` says whether its FCM
    reached its fixed point.

    **Example:**

    ```python
    h = fx.build_hierarchy(space.embedding, space.geodesics)
    hs = fx.build_hierarchy(es.embedding, es.graph, levels=5,
                            fcm=fx.navigation.TruncatedFuzzyCMeans(nearest=8))
    ```
    """
    fcm, rule = _options(fcm, links, dict(deprecated))
    x = jnp.asarray(embedding)
    if x.ndim != 2:
        raise FxspaceError(f"embedding must be (T, d), got shape {x.shape}")
    if not bool(jnp.all(jnp.isfinite(x))):
        raise FxspaceError(
            "embedding has NaN/inf rows: build the expression space on a "
            "connected graph (see threshold_sweep) before the hierarchy"
        )
    T = x.shape[0]
    sizes = level_sizes(T, c0)
    below = [c for c in sizes if c < T]
    if levels is not None:
        below = below[: check_int(levels, "levels", low=1)]
    sizes = tuple(below) + ((T,) if finest or not below else ())
    key = jax.random.PRNGKey(0) if key is None else key
    # the later levels' FCM kernels compiled in a thread while the first level runs
    comp = ThreadPoolExecutor(1, thread_name_prefix="fxspace-compile")
    ahead = comp.submit(fcm.precompile, x, [c for c in sizes[1:] if c < T])
    try:
        if paths is None or rule is None:
            out = Hierarchy(tuple(_fcm_levels(x, sizes, T, key, fcm)), np.asarray(x))
            ahead.result()  # a failure there is a bug: said, not hidden
            return out
        return _linked(x, paths, rule, sizes, T, key, fcm, ahead)
    finally:
        comp.shutdown(wait=True, cancel_futures=True)


def _linked(x, paths, rule, sizes, T, key, fcm, ahead) -> Hierarchy:
    """The levels and their links: each level's links made in a thread as its FCM ends,
    while the next level's runs (the same work as one after another: the same
    hierarchy), and the finest level's steps tested in a thread of their own from the
    start."""
    pool = ThreadPoolExecutor(1, thread_name_prefix="fxspace-links")
    pre = ThreadPoolExecutor(1, thread_name_prefix="fxspace-steps")
    try:
        linker = _Linker(np.asarray(x, np.float64), paths, rule, sizes, pool, pre)
        for lv in _fcm_levels(x, sizes, T, key, fcm):
            linker.add(lv)
        out = linker.hierarchy(np.asarray(x))
        ahead.result()
        return out
    finally:  # on an error or an interrupt, the links not started are dropped
        pool.shutdown(wait=True, cancel_futures=True)
        pre.shutdown(wait=True, cancel_futures=True)


@checked
def relink(
    hierarchy: Hierarchy,
    paths,
    rho_scale: float = 0.5,
    *,
    bridges: bool = False,
    max_link_centres: int | None = None,
) -> Hierarchy:
    """The same levels with their links made again at ρ = ``rho_scale`` × each level's
    centre spacing (``bridges`` as in `LinkRule`); the centres and memberships are
    untouched. What a ρ chosen by `link_radius_sweep` is applied with."""
    if not float(rho_scale) >= 0:
        raise FxspaceError(f"rho_scale must be >= 0, got {rho_scale}")
    rule = LinkRule(rho=float(rho_scale), bridges=bool(bridges), max_centres=max_link_centres)
    return _link_all(hierarchy, paths, rule)


@checked
def cold_levels(
    embedding: Float[Array, "T d"],
    *,
    c0: int = 10,
    m: float = 2.0,
    key: Array | None = None,
    tol: float = 1e-4,
    max_steps: int = 300,
    criterion: Literal["max", "fro"] = "max",
) -> list[dict]:
    """The warm start's benchmark, apart from the hierarchy: for every warm-started level
    of `build_hierarchy` (not the first, not the finest), fuzzy c-means from one
    k-means++ seed drawn from the same key sequence (each level's ``k_cold``). Returns
    ``[{"n_clusters", "num_steps_cold", "objective_cold"}]`` per level (``-1``/NaN where
    no cold run applies)."""
    x = jnp.asarray(embedding)
    T = x.shape[0]
    key = jax.random.PRNGKey(0) if key is None else key
    out = []
    for li, c in enumerate(level_sizes(T, c0)):
        key, k_cold, _ = jax.random.split(key, 3)
        steps, obj = -1, float("nan")
        if 0 < li and c < T:
            cold = fuzzy_cmeans(x, c, m, key=k_cold, tol=tol, max_steps=max_steps,
                                criterion=criterion)  # fmt: skip
            steps, obj = int(cold.num_steps), float(cold.objective)
        out.append({"n_clusters": int(c), "num_steps_cold": steps, "objective_cold": obj})
    return out


def finest_level(
    embedding: Float[Array, "T 2"],
    paths,
    *,
    links: bool = True,
    rho: float | None = None,
) -> Level:
    """The level where every frame is a centre (c = T): no clustering (the trivial FCM
    record), links by the rule at ``rho`` (default 0.5 × the frames' median spacing)."""
    x = np.asarray(as_float_array(embedding, "embedding", ndim=2, xp="numpy"), np.float64)
    if links and not hasattr(paths, "steps"):
        raise FxspaceError(
            f"paths must be the frames' Geodesics or NeighbourGraph (fxspace.expression.Paths),"
            f" got {type(paths).__name__}"
        )
    T = len(x)
    lv = Level(T, x.copy(), np.arange(T, dtype=np.int64), _frames_fit(x),
               stats={"init": "frames", "num_steps_split": -1, "total_steps": 0})  # fmt: skip
    r = default_link_radius(x, 0.5) if rho is None else float(rho)
    if not links:
        empty = pair_csr([], [], np.zeros(0, bool), T)
        return lv._replace(links=empty, bridges=empty, lengths=pair_csr([], [], np.zeros(0), T),
                           radius=r)  # fmt: skip
    lk, br, ln = level_links(x, paths, lv.center_frames, r, LinkRule(rho=0.5))
    return lv._replace(links=lk, bridges=br, lengths=ln, radius=r)


def frame_links(paths, embedding: Float[Array, "T 2"], rho: float | None = None):
    """``(links, bridges)`` of the level where every frame is a centre (`finest_level`)."""
    lv = finest_level(embedding, paths, rho=rho)
    return lv.links, lv.bridges
