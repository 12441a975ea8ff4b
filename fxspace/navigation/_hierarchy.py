"""The hierarchy of fuzzy c-means levels over the 2-D expression space, and the links
between centres that navigation may follow.

Seed paper §4: level l has c_l = c0·2^l centres (c0 ≈ 10), up to the level that shows
every frame (c_L = T, the number of frames); each centre is shown as its nearest
frame. Level l+1 is warm-started from level l by *splitting* centres (LBG-style): the
centres that contribute most to the objective are replaced by two children at
v ± 0.8 σ r, r the principal axis of the cluster's fuzzy covariance and σ² its
variance along r (for a Gaussian cluster the halves' centroids lie at ±0.8 σ).

Two centres are *linked* when the geodesic (frame-graph) path between their frames,
drawn in 2-D, passes within ρ of no other centre; ρ is a scale × the level's median
nearest-centre spacing, the scale chosen by the paper's experiment. With
``bridges=True`` a level the rule leaves in pieces is joined by the cheapest (geodesic)
links between them (*bridges*, outside the rule).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_int, check_scalar, checked
from fxspace.cluster import (
    FCMResult,
    fuzzy_cmeans,
    kmeanspp_extend,
    kmeanspp_init,
    squared_distances,
)
from fxspace.errors import FxspaceError
from fxspace.navigation._links import (
    LINK_SCALES,
    LinkRadiusSweep,
    _sweep,
    add_bridges,
    center_links,
    choose_link_scale,
    default_link_radius,
    link_graph_connected,
)
from fxspace.results import RESULTS, member_code, result_from_code

__all__ = [
    "cold_levels",
    "Level",
    "Hierarchy",
    "level_sizes",
    "split_centers",
    "nearest_frames",
    "center_links",
    "default_link_radius",
    "build_hierarchy",
    "link_graph_connected",
    "hierarchy_to_arrays",
    "hierarchy_from_arrays",
]


class Level(NamedTuple):
    """One level of the hierarchy.

    **Fields:**

    - `n_clusters`: c_l.
    - `centers`: (c, 2) FCM centres in the expression space.
    - `memberships`: (T, c) fuzzy memberships of every frame.
    - `center_frames`: (c,) the frame nearest each centre (how a centre is shown).
    - `objective`, `num_steps`: the winning FCM run's objective and iterations.
    - `result`: its [`RESULTS`][fxspace.RESULTS] member (`converged` is derived from it).
    - `links`: (c, c) symmetric bool, False on the diagonal (None if not computed).
    - `bridges`: (c, c) bool, the subset of `links` added only to keep the level connected.
    - `radius`: the ρ used for the links.
    - `stats`: how the level was started: ``init`` (the start that won: ``"split"``,
      ``"kmeans++-extend"``, ``"kmeans++"`` or ``"frames"`` for c = T),
      ``num_steps_split`` (iterations of the split start alone, -1 when not run) and
      ``total_steps`` (iterations of all starts together: the level's cost). Also read
      as the properties `init`, `num_steps_split`, `total_steps`.

    Timings and the cold-start comparison are benchmarks, not part of a level: see
    `cold_levels` and the navigation pipeline's metrics.
    """

    n_clusters: int
    centers: np.ndarray
    memberships: np.ndarray
    center_frames: np.ndarray
    objective: float
    num_steps: int
    result: Any
    links: np.ndarray | None
    bridges: np.ndarray | None
    radius: float
    stats: dict[str, Any]

    @property
    def converged(self) -> bool:
        """``result == RESULTS.successful`` (derived, not stored)."""
        return bool(self.result == RESULTS.successful)

    @property
    def init(self) -> str:
        return str(self.stats.get("init", ""))

    @property
    def num_steps_split(self) -> int:
        return int(self.stats.get("num_steps_split", -1))

    @property
    def total_steps(self) -> int:
        return int(self.stats.get("total_steps", -1))

    @property
    def labels(self) -> np.ndarray:
        """(T,) each frame's hard cluster at this level (largest membership)."""
        return np.argmax(self.memberships, axis=1)

    def neighbours(self, k: int) -> np.ndarray:
        """Centres linked to centre ``k``."""
        if self.links is None:
            raise FxspaceError("this level has no links; build the hierarchy with geodesics")
        return np.flatnonzero(self.links[k])


class Hierarchy(NamedTuple):
    """All levels, coarse to fine, over one 2-D embedding."""

    levels: tuple[Level, ...]
    embedding: np.ndarray
    link_sweep: Any = None
    """The `LinkRadiusSweep` that chose ρ (``rho_scale="experiment"``), else None."""

    @property
    def sizes(self) -> tuple[int, ...]:
        return tuple(lv.n_clusters for lv in self.levels)


@checked
def level_sizes(n_frames: int, c0: int = 10) -> tuple[int, ...]:
    """c0, 2c0, 4c0, … while below ``n_frames``, then ``n_frames`` (the level showing every
    frame). The number of levels is ⌈log2(T / c0)⌉ + 1."""
    if int(c0) < 1:
        raise FxspaceError(f"c0 must be >= 1, got {c0}")
    if int(n_frames) < 1:
        raise FxspaceError(f"n_frames must be >= 1, got {n_frames}")
    sizes = []
    c = int(c0)
    while c < n_frames:
        sizes.append(c)
        c *= 2
    sizes.append(int(n_frames))
    return tuple(sizes)


@partial(jax.jit, static_argnames=("n_new", "m", "power_steps", "symmetric", "hard"))
def _split(
    x,
    centers,
    memberships,
    n_new: int,
    m: float,
    alpha=0.8,
    symmetric: bool = True,
    power_steps: int = 8,
    hard: bool = True,
):
    um = jnp.power(memberships, m)
    if hard:
        # FCM's memberships have heavy tails (u ~ d^-2), which inflate a fuzzy covariance;
        # the split uses the samples each centre wins
        um = um * (jnp.argmax(memberships, axis=1)[:, None] == jnp.arange(um.shape[1])[None, :])
    mass = jnp.maximum(jnp.sum(um, axis=0), jnp.finfo(x.dtype).tiny)
    d2 = squared_distances(x, centers)
    contribution = jnp.sum(um * d2, axis=0)
    order = jnp.argsort(-contribution)[:n_new]
    # power iteration for the principal axis of each cluster's fuzzy covariance,
    # C_k r = Σ_i u_ik^m (x_i − v_k)((x_i − v_k)·r) / Σ_i u_ik^m, without (n, c, d) temporaries
    r0 = jnp.ones_like(centers) / jnp.sqrt(centers.shape[1])
    r0 = r0.at[:, 0].add(0.1)

    def cov_times(r):
        proj = x @ r.T - jnp.sum(centers * r, axis=1)[None, :]
        w = um * proj
        return (w.T @ x - centers * jnp.sum(w, axis=0)[:, None]) / mass[:, None]

    def step(r, _):
        cr = cov_times(r)
        nrm = jnp.linalg.norm(cr, axis=1, keepdims=True)
        return jnp.where(nrm > 0, cr / jnp.where(nrm > 0, nrm, 1.0), r), None

    r, _ = jax.lax.scan(step, r0 / jnp.linalg.norm(r0, axis=1, keepdims=True), None, power_steps)
    lam = jnp.maximum(jnp.sum(r * cov_times(r), axis=1), 0.0)
    step = alpha * jnp.sqrt(lam)[:, None] * r
    child = centers + step
    if symmetric:
        parent = centers.at[order].add(-step[order])
    else:
        parent = centers
    return jnp.concatenate([parent, child[order]], axis=0)


def split_centers(
    x: Float[Array, "n d"],
    centers: Float[Array, "c d"],
    memberships: Float[Array, "n c"],
    n_clusters: int,
    m: float = 2.0,
) -> Float[Array, "c2 d"]:
    """Initial centres for a finer level: the ``n_clusters − c`` centres with the largest
    share of the objective are each replaced by two children at v ± 0.8 σ r (r: principal
    axis of the cluster's fuzzy covariance, by power iteration; σ²: variance along r)."""
    x = as_float_array(x, "x", ndim=2)
    centers = as_float_array(centers, "centers", shape=(None, x.shape[1]))
    c = centers.shape[0]
    memberships = as_float_array(memberships, "memberships", shape=(x.shape[0], c))
    n_clusters = check_int(n_clusters, "n_clusters")
    m = check_scalar(m, "m", low=1.0, low_open=True)
    if not c <= n_clusters <= 2 * c:
        raise FxspaceError(
            f"n_clusters must lie in [{c}, {2 * c}] to split {c} centres, got {n_clusters}"
        )
    if n_clusters == c:
        return jnp.asarray(centers)
    return _split(
        jnp.asarray(x), jnp.asarray(centers), jnp.asarray(memberships), n_clusters - c, float(m)
    )


@jax.jit
def _nearest(x, centers):
    return jnp.argmin(squared_distances(centers, x), axis=1).astype(jnp.int32)


def nearest_frames(embedding: Float[Array, "T d"], centers: Float[Array, "c d"]) -> np.ndarray:
    """(c,) index of the frame nearest each centre (how each centre is shown)."""
    embedding = as_float_array(embedding, "embedding", ndim=2)
    centers = as_float_array(centers, "centers", shape=(None, embedding.shape[1]))
    return np.asarray(_nearest(embedding, centers))


def _level_starts(x, c, prev, k_cold, k_ext, *, warm_start, restarts, split,
                  first_level_seeds, m) -> list:  # fmt: skip
    """The FCM starts of one level: the frames themselves (c = T), k-means++ seeds (first
    level or cold), else the split of the coarser centres + k-means++-extend draws."""
    if c == x.shape[0]:
        return [x]
    if prev is None or not warm_start:
        n_seeds = max(1 + restarts, first_level_seeds if prev is None else 1)
        return [kmeanspp_init(x, c, k) for k in jax.random.split(k_cold, n_seeds)]
    n_new = c - prev.centers.shape[0]
    starts = [split_centers(x, prev.centers, prev.memberships, c, m)] if split else []
    return starts + [
        kmeanspp_extend(x, prev.centers, n_new, k) for k in jax.random.split(k_ext, restarts)
    ]


def _level(x, c: int, T: int, res, runs, best: int, prev, geodesics, max_link_centres,
           rho_scale: float, warm_start: bool, split: bool, bridges: bool) -> Level:  # fmt: skip
    """One `Level` of `build_hierarchy` from its winning FCM run: the centres' frames, the
    links (with ``geodesics``), how it was started."""
    frames = nearest_frames(x, res.centers)
    links = added = None
    rho = float("nan")
    if geodesics is not None and (max_link_centres is None or c <= max_link_centres):
        rho = default_link_radius(np.asarray(x)[frames], rho_scale)
        links, added = center_links(x, geodesics, frames, rho, bridge=bridges)
    if c == T:
        init_name = "frames"
    elif prev is None or not warm_start:
        init_name = "kmeans++"
    else:
        init_name = "split" if (split and best == 0) else "kmeans++-extend"
    split_steps = -1
    if split and init_name.startswith(("split", "kmeans++-")):
        split_steps = int(runs[0].num_steps)
    return Level(
        n_clusters=c,
        centers=np.asarray(res.centers),
        memberships=np.asarray(res.memberships),
        center_frames=frames,
        objective=float(res.objective),
        num_steps=int(res.num_steps),
        result=res.result,
        links=links,
        bridges=added,
        radius=rho,
        stats={"init": init_name, "num_steps_split": split_steps,
               "total_steps": int(sum(int(r.num_steps) for r in runs))},
    )  # fmt: skip


@checked
def build_hierarchy(
    embedding: Float[Array, "T d"],
    geodesics=None,
    *,
    c0: int = 10,
    m: float = 2.0,
    key: Array | None = None,
    tol: float = 1e-4,
    max_steps: int = 300,
    warm_start: bool = True,
    restarts: int = 1,
    split: bool = True,
    first_level_seeds: int = 8,
    rho_scale: float | Literal["experiment"] = "experiment",
    max_link_centres: int | None = None,
    criterion: Literal["max", "fro"] = "max",
    bridges: bool = False,
    link_sweep_max_centres: int = 320,
) -> Hierarchy:
    """Fuzzy c-means levels c0·2^l (seed §4) over the expression-space ``embedding``.

    **Arguments:**

    - `embedding`: (T, 2) MDS coordinates (any (T, d) works for the clustering).
    - `geodesics`: the frame graph's ``Geodesics`` (distances, next_hop); when given,
      every level gets its links (see `center_links`).
    - `c0`: centres at the coarsest level; sizes from `level_sizes`.
    - `m`, `tol`, `max_steps`, `criterion`: FCM settings (see `fuzzy_cmeans`).
    - `key`: PRNG key for the k-means++ draws.
    - `warm_start`: start level l+1 from level l: its centres split
      (`split_centers`) and, with ``restarts`` ≥ 1, also ``restarts`` runs that keep
      the coarse centres and draw the new ones k-means++-style (`kmeanspp_extend`);
      the lowest objective of all starts wins. Without it,
      every level is seeded from scratch (k-means++, 1 + ``restarts`` seeds).
    - `split`: include the split start (False: only the ``restarts`` k-means++-extend starts,
      which need ``restarts`` ≥ 1).
    - `first_level_seeds`: k-means++ seeds at the first level (cheap there, and it decides
      the coarse structure every finer level inherits).
    - `rho_scale`: ρ = rho_scale × median nearest-centre spacing of the level; with
      ``"experiment"`` (default) the paper's experiment chooses it: `link_radius_sweep`
      over `LINK_SCALES` on the levels of at most `link_sweep_max_centres` centres, and
      `choose_link_scale` (the largest scale that keeps them all connected); the sweep
      is kept as ``Hierarchy.link_sweep``.
    - `max_link_centres`: skip links for levels with more centres (None: all levels).
    - `bridges`: False (default): the paper's rule alone; a level may then fall apart
      into pieces that no route joins (at AnimFace's finer levels, centres closer than
      ρ to another, whose every path passes that one). True: where a level's links
      leave it in pieces, the geodesically cheapest link between two pieces is added
      (``Level.bridges``, outside the rule, counted and drawn apart).

    **Returns:** a `Hierarchy`. At the finest level c = T: k-means++ seeding draws
    every frame, the global optimum (J = 0), so its start is the frames themselves.
    """
    x = jnp.asarray(embedding)
    if x.ndim != 2:
        raise FxspaceError(f"embedding must be (T, d), got shape {x.shape}")
    if not bool(jnp.all(jnp.isfinite(x))):
        raise FxspaceError(
            "embedding has NaN/inf rows: build the expression space on a "
            "connected graph (see threshold_sweep) before the hierarchy"
        )
    if int(restarts) < 0:
        raise FxspaceError(f"restarts must be >= 0, got {restarts}")
    if not split and int(restarts) < 1:
        raise FxspaceError("split=False needs restarts >= 1 (the k-means++-extend starts)")
    experiment = isinstance(rho_scale, str)
    if experiment and rho_scale != "experiment":
        raise FxspaceError(f"rho_scale must be a number >= 0 or 'experiment', got {rho_scale!r}")
    T = x.shape[0]
    if key is None:
        key = jax.random.PRNGKey(0)
    fcm_kw = dict(tol=tol, max_steps=max_steps, criterion=criterion)
    opts = dict(warm_start=warm_start, restarts=restarts, split=split,
                first_level_seeds=first_level_seeds, m=m)  # fmt: skip
    levels: list[Level] = []
    prev: FCMResult | None = None
    for c in level_sizes(T, c0):
        key, k_cold, k_ext = jax.random.split(key, 3)
        inits = _level_starts(x, c, prev, k_cold, k_ext, **opts)
        # the starts run one after another: on CPU a vmapped while-loop costs more than the
        # sum of the single runs (every lane pays for the slowest)
        runs = [
            jax.block_until_ready(fuzzy_cmeans(x, c, m, init_centers=v, **fcm_kw)) for v in inits
        ]
        objs = np.asarray([float(r.objective) for r in runs])
        best = int(np.argmin(np.where(np.isnan(objs), np.inf, objs)))
        res = runs[best]
        levels.append(_level(
            x, c, T, res, runs, best, prev, None if experiment else geodesics,
            max_link_centres, 0.0 if experiment else rho_scale, warm_start, split, bridges,
        ))  # fmt: skip
        prev = res
    h = Hierarchy(tuple(levels), np.asarray(x))
    if experiment and geodesics is not None:
        sweep, clears = _sweep(h, geodesics, LINK_SCALES, link_sweep_max_centres)
        h = _relink(h, geodesics, choose_link_scale(sweep), bridges, max_link_centres, clears)
        h = h._replace(link_sweep=sweep)
    return h


@checked
def relink(
    hierarchy: Hierarchy,
    geodesics,
    rho_scale: float = 0.5,
    *,
    bridges: bool = False,
    max_link_centres: int | None = None,
) -> Hierarchy:
    """The same levels with their links made again at ρ = ``rho_scale`` × each level's
    centre spacing (`center_links`; ``bridges`` as in `build_hierarchy`); the centres
    and memberships are untouched. What a ρ chosen by `link_radius_sweep` is applied with,
    without clustering again."""
    if rho_scale < 0:
        raise FxspaceError(f"rho_scale must be >= 0, got {rho_scale}")
    return _relink(hierarchy, geodesics, rho_scale, bridges, max_link_centres, {})


def _relink(hierarchy, geodesics, rho_scale, bridges, max_link_centres, clears) -> Hierarchy:
    """`relink`, reading a level's links off its clearances when ``clears`` has them."""
    x = np.asarray(hierarchy.embedding)
    out = []
    for i, lv in enumerate(hierarchy.levels):
        links = added = None
        rho = float("nan")
        if max_link_centres is None or lv.n_clusters <= max_link_centres:
            rho = default_link_radius(x[lv.center_frames], rho_scale)
            if i in clears:  # exact clearances from the ρ experiment
                links = clears[i] >= rho
                np.fill_diagonal(links, False)
                added = (add_bridges(links, geodesics, lv.center_frames) if bridges
                         else np.zeros_like(links))  # fmt: skip
            else:
                links, added = center_links(x, geodesics, lv.center_frames, rho, bridge=bridges)
        out.append(lv._replace(links=links, bridges=added, radius=rho))
    return Hierarchy(tuple(out), hierarchy.embedding, hierarchy.link_sweep)


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
    k-means++ seed drawn from the same key sequence (each level's ``k_cold``). The
    hierarchy an app builds runs none of it. Returns ``[{"n_clusters", "num_steps_cold",
    "objective_cold"}]`` per level (``-1``/NaN where no cold run applies)."""
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


_LEVEL_SCALARS = ("n_clusters", "objective", "num_steps", "radius")
_LEVEL_STATS = ("num_steps_split", "total_steps")


@checked
def hierarchy_to_arrays(h: Hierarchy) -> dict[str, np.ndarray]:
    """A flat ``{name: array}`` of a `Hierarchy` (for `fxspace.runs.cached_arrays` or an
    ``.npz``; no pickles): ``embedding``, ``n_levels`` and, per level ``i``,
    ``l{i}_centers``, ``l{i}_memberships`` (float32), ``l{i}_center_frames``,
    ``l{i}_links``/``l{i}_bridges`` (absent when not computed), ``l{i}_result`` (the
    `RESULTS` code), ``l{i}_init`` and the scalars and stats. `hierarchy_from_arrays` inverts it."""
    out: dict[str, np.ndarray] = {
        "embedding": np.asarray(h.embedding), "n_levels": np.asarray(len(h.levels)),
    }  # fmt: skip
    for i, lv in enumerate(h.levels):
        p = f"l{i}_"
        out[p + "centers"] = np.asarray(lv.centers)
        out[p + "memberships"] = np.asarray(lv.memberships, np.float32)
        out[p + "center_frames"] = np.asarray(lv.center_frames)
        out[p + "init"] = np.asarray(lv.init)
        if lv.links is not None:
            out[p + "links"] = np.asarray(lv.links, bool)
            out[p + "bridges"] = np.asarray(lv.bridges, bool)
        out[p + "result"] = np.asarray(member_code(lv.result))
        for f in _LEVEL_SCALARS:
            out[p + f] = np.asarray(getattr(lv, f))
        for f in _LEVEL_STATS:
            out[p + f] = np.asarray(lv.stats.get(f, -1))
    if h.link_sweep is not None:
        for f, v in h.link_sweep._asdict().items():
            out["link_sweep_" + f] = np.asarray(v)
    return out


@checked
def hierarchy_from_arrays(a: dict[str, np.ndarray]) -> Hierarchy:
    """The `Hierarchy` stored by `hierarchy_to_arrays`."""
    if not hasattr(a, "__getitem__") or not hasattr(a, "__contains__") or isinstance(a, str):
        raise FxspaceError(
            f"a must be the arrays of hierarchy_to_arrays (a dict or an NpzFile), got "
            f"{type(a).__name__}"
        )
    try:
        n = int(a["n_levels"])
        levels = []
        for i in range(n):
            p = f"l{i}_"
            sc = {f: a[p + f].item() for f in _LEVEL_SCALARS}
            levels.append(Level(
                centers=np.asarray(a[p + "centers"]),
                memberships=np.asarray(a[p + "memberships"]),
                center_frames=np.asarray(a[p + "center_frames"]),
                links=np.asarray(a[p + "links"]) if p + "links" in a else None,
                bridges=np.asarray(a[p + "bridges"]) if p + "bridges" in a else None,
                result=result_from_code(a[p + "result"].item()),
                stats={"init": str(a[p + "init"]),
                       **{f: int(a[p + f].item()) for f in _LEVEL_STATS}},
                **sc,
            ))  # fmt: skip
        sweep = None
        if "link_sweep_scales" in a:
            sweep = LinkRadiusSweep(*(np.asarray(a["link_sweep_" + f])
                                      for f in LinkRadiusSweep._fields))  # fmt: skip
        return Hierarchy(tuple(levels), np.asarray(a["embedding"]), sweep)
    except KeyError as e:
        raise FxspaceError(f"not a stored hierarchy: {e} missing") from None
