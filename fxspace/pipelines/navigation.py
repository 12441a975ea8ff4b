"""Hierarchical navigation of the expression space (Kim & Jung §2–4), at every size.

One pipeline for 10³ to 10⁵ frames and more: ``[graph] kind`` says how the frames are
joined — ``"epsilon"`` (the paper's ε-graph: ``T × T`` geodesics and next hops, MDS) or
``"knn"`` (a k-nearest-neighbour graph, landmark geodesics and landmark MDS: memory
O(T·k)); unset, it is chosen by the number of frames (``epsilon`` up to
``graph.epsilon_max_frames``). Everything after it — the FCM levels, their links by the
paper's rule with ρ by its experiment, routes, the navigator — is the same code
(`fxspace.navigation`, on the frames' *paths*).

Loads facial frames (AnimFace takes or the synthetic face), chooses ε by the paper's rule
on *these* frames (``threshold = "max_r"``: a threshold sweep from the connecting ε to the
largest distance, highest Pearson r; or ``"bounded_degree"``/``"elbow"``, a number in mm,
``"from:RUN_DIR"`` — a finished threshold-sweep run — or 0 for ``threshold_factor`` × the
connecting ε; recorded as ``threshold_source``), builds the expression space, the fuzzy
c-means levels (warm-started, and cold for comparison) and their links, runs a scripted
navigation (key centres at the first level refined automatically to the finest) and
writes the level figures, the grid of all levels, the animation, the routes and the
hierarchy.

Stages (`STAGES`, cached in ``run_dir/cache``; an interrupted run resumes, and the
navigator app reads them instead of recomputing): ``sweep`` (only when ε comes from a
criterion), ``space`` (geodesics, next hops, 2-D MDS; or the k-NN graph and its landmark
MDS) and ``hierarchy`` (every level).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, NamedTuple

import jax
import numpy as np

from fxspace._progress import progress, stage
from fxspace.config import ConfigError
from fxspace.datasets import FaceData, load_face
from fxspace.errors import FxspaceError
from fxspace.expression import (
    Geodesics,
    NeighbourGraph,
    SweepResult,
    check_sparse_connected,
    choose_threshold,
    connecting_threshold,
    epsilon_graph,
    expression_space,
    farthest_point_landmarks,
    landmark_mds,
    landmark_score,
    neighbourhood_graph_blocks,
    threshold_grid,
)
from fxspace.navigation import (
    SWEEP_THRESHOLDS,
    THRESHOLD_CRITERIA,
    FuzzyCMeans,
    Hierarchy,
    LinkRule,
    TruncatedFuzzyCMeans,
    build_hierarchy,
    cold_levels,
    hierarchy_from_arrays,
    hierarchy_to_arrays,
    is_graph_walk,
    link_components,
    link_graph_connected,
    navigate,
    playback,
    threshold_from_run,
)
from fxspace.pipelines._dask import check_stage_scheduler, dask_client
from fxspace.pipelines.threshold_sweep import state_distances, sweep_stage
from fxspace.results import result_message
from fxspace.runs import (
    cached,
    cached_arrays,
    save_figure_atomic,
    save_npz_atomic,
    write_json_atomic,
)

__all__ = [
    "Config",
    "GraphConfig",
    "HierarchyConfig",
    "NavConfig",
    "NavSpace",
    "STAGES",
    "prepare_app",
    "run",
    "load_space",
    "auto_key_centres",
    "build_levels",
    "graph_kind",
]

GRAPH_KINDS = ("epsilon", "knn")

STAGES = ("sweep", "space", "hierarchy", "cold_levels")
APP = "fxspace.studio._navigator:serve"  # `fxspace studio` of a run: the navigator


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """ε: a criterion (``"max_r"`` — the paper's, default; ``"bounded_degree"``,
    ``"elbow"``) swept here over ``num_thresholds`` thresholds from the connecting ε to
    the largest distance, on the navigated frames; a number (mm: the Frobenius distance
    between marker-distance matrices); ``"from:RUN_DIR"`` — the ε a finished
    threshold-sweep run chose; or 0 for ``threshold_factor`` × the smallest threshold that
    connects the graph. The metrics record which (``threshold_source``).

    ``kind``: ``"epsilon"`` (that ε-graph, dense geodesics) or ``"knn"`` (``k`` nearest
    neighbours per frame on the marker-distance features, ``landmarks`` max-min
    landmarks for the geodesics and the landmark MDS); unset (""), ``epsilon`` up to
    ``epsilon_max_frames`` frames, else ``knn``.

    ``scheduler`` (``knn``): where the graph's per-block stages run
    (`fxspace.expression.neighbourhood_graph_blocks`) — "" in this process, ``"local"`` a
    local Dask cluster of ``workers`` processes, or a running Dask scheduler's address
    (``tcp://HOST:PORT``; its workers must reach the run folder). The graph, and so
    the whole run, is the same wherever it runs."""

    kind: str = ""
    threshold: float | str = "max_r"
    threshold_factor: float = 1.25
    num_thresholds: int = SWEEP_THRESHOLDS
    dtype: Literal["float32", "float64"] = "float32"
    k: int = 10
    landmarks: int = 256
    epsilon_max_frames: int = 5000
    scheduler: str = ""
    workers: int = 2

    def validate(self) -> None:
        check_stage_scheduler(self.scheduler, self.workers)
        if self.kind not in ("", *GRAPH_KINDS):
            raise ConfigError(
                f"graph.kind must be one of {GRAPH_KINDS} (or unset), got {self.kind!r}"
            )
        if self.k < 2:
            raise ConfigError("graph.k must be >= 2 (neighbours per frame)")
        if self.landmarks < 3:
            raise ConfigError("graph.landmarks must be >= 3 (MDS in 2-D needs 3)")
        if isinstance(self.threshold, str):
            if not (self.threshold.startswith("from:") or self.threshold in THRESHOLD_CRITERIA):
                raise ConfigError(
                    f"graph.threshold must be a number, 'from:RUN_DIR' or one of "
                    f"{THRESHOLD_CRITERIA}; got {self.threshold!r}"
                )
        elif not self.threshold >= 0:
            raise ConfigError("graph.threshold must be >= 0 (0: use graph.threshold_factor)")
        if not self.threshold_factor >= 1.0:
            raise ConfigError(
                "graph.threshold_factor must be >= 1 (below 1 the graph is disconnected)"
            )
        if self.num_thresholds < 2:
            raise ConfigError("graph.num_thresholds must be >= 2")


@dataclasses.dataclass(frozen=True)
class HierarchyConfig:
    """FCM levels c0·2^l (see `fxspace.build_hierarchy`): ``levels`` of them (0: every
    one below the number of frames) and, with ``finest``, the level where every frame is
    a centre. On a ``knn`` graph the memberships keep each frame's ``nearest`` centres
    (`fxspace.navigation.TruncatedFuzzyCMeans`). ``max_steps`` / ``restarts``
    left at -1 take the solver's default (300 / 1 for the full FCM, 2000 / 0 for the
    truncated one); ``max_steps`` is a cap only: a level stopped by it says so
    in the metrics (``levels[i].result``) and on the navigator's status line."""

    c0: int = 10
    m: float = 2.0
    tol: float = 1e-4
    max_steps: int = -1
    restarts: int = -1
    levels: int = 0
    finest: bool = True
    nearest: int = 8
    rho_scale: float | str = "experiment"  # or a number: ρ = rho_scale × centre spacing
    bridges: bool = False  # true: join the pieces a level is left in (links outside the ρ rule)
    link_sweep_max_centres: int = 320  # levels the ρ experiment looks at
    compare_cold: bool = True  # (full FCM only: the epsilon graph's levels)
    max_link_centres: int = 0  # 0: links at every level

    def validate(self) -> None:
        if self.c0 < 1 or not self.m > 1 or not self.tol > 0:
            raise ConfigError("hierarchy: need c0 >= 1, m > 1, tol > 0")
        if self.max_steps == 0 or self.max_steps < -1:
            raise ConfigError("hierarchy.max_steps must be >= 1 (or -1: the solver's default)")
        if self.levels < 0 or self.nearest < 1:
            raise ConfigError("hierarchy: need levels >= 0 (0: all) and nearest >= 1")
        if isinstance(self.rho_scale, str):
            if self.rho_scale != "experiment":
                raise ConfigError("hierarchy.rho_scale must be a number > 0 or 'experiment'")
        elif not self.rho_scale > 0:
            raise ConfigError("hierarchy.rho_scale must be > 0 (or 'experiment')")
        if self.link_sweep_max_centres < self.c0:
            raise ConfigError("hierarchy.link_sweep_max_centres must be >= c0")
        if self.restarts < -1:
            raise ConfigError("hierarchy.restarts must be >= 0 (or -1: the solver's default)")
        if self.max_link_centres < 0:
            raise ConfigError("hierarchy.max_link_centres must be >= 0 (0: every level)")


@dataclasses.dataclass(frozen=True)
class NavConfig:
    """Scripted navigation: ``key_centres`` at the first level (empty: ``num_keys`` centres
    chosen automatically along links), refined to the finest level, played at ``fps``."""

    key_centres: tuple[int, ...] = ()
    num_keys: int = 4
    fps: float = 30.0
    duration: float = 0.0  # 0: one captured frame per 1/rate s
    by: Literal["arclength", "frame"] = "arclength"
    animation: Literal["gif", "mp4", "none"] = "gif"
    animation_frames: int = 200
    level_figures: bool = True
    figure: bool = True  # False: no figures nor animation (routes and metrics only)

    def validate(self) -> None:
        if self.num_keys < 2 and not self.key_centres:
            raise ConfigError("navigation.num_keys must be >= 2")
        if not self.fps > 0:
            raise ConfigError("navigation.fps must be > 0")
        if not self.duration >= 0:
            raise ConfigError("navigation.duration must be >= 0 (0: the capture's rate)")
        if self.animation_frames < 2:
            raise ConfigError("navigation.animation_frames must be >= 2")
        if any(k < 0 for k in self.key_centres):
            raise ConfigError("navigation.key_centres must be centre numbers >= 0")


@dataclasses.dataclass(frozen=True)
class Config:
    data: FaceData = FaceData(max_frames=2400)
    graph: GraphConfig = GraphConfig()
    hierarchy: HierarchyConfig = HierarchyConfig()
    navigation: NavConfig = NavConfig()

    def validate(self) -> None:
        for part in (self.graph, self.hierarchy, self.navigation):
            part.validate()


class NavSpace(NamedTuple):
    """What navigation (and the navigator app) needs, from the cached stages, for either
    graph kind: the embedding, the frames' `paths` (``Geodesics`` on the ε-graph, the
    `NeighbourGraph` on the k-NN one: `fxspace.expression.Paths`), the hierarchy, ε and
    where it came from (the k-NN graph's ``k`` there), the embedding's r."""

    embedding: np.ndarray
    paths: Geodesics | NeighbourGraph
    hierarchy: Hierarchy
    threshold: float
    threshold_source: str
    connecting_threshold: float
    r: float
    sweep: SweepResult | None
    choice: dict | None
    kind: str = "epsilon"

    @property
    def geodesics(self):
        """The frames' paths (the old name of `paths`)."""
        return self.paths


def _stage(run_dir: Path | None, name: str, compute: Callable[[], dict]) -> dict:
    if run_dir is None:
        return {k: np.asarray(v) for k, v in compute().items()}
    return cached_arrays(run_dir, name, compute)


def _threshold(cfg: GraphConfig, P: Callable, run_dir: Path | None):
    """``(ε, source, sweep, choice)`` as the config says (the sweep: a cached stage)."""
    t = cfg.threshold
    if isinstance(t, str) and t.startswith("from:"):
        try:
            eps, crit = threshold_from_run(t.removeprefix("from:"))
        except FxspaceError as e:
            raise ConfigError(f"graph.threshold: {e}") from e
        return eps, f"{t} ({crit})", None, None
    if isinstance(t, str):
        stage(f"threshold sweep over these frames ({cfg.num_thresholds} ε, criterion {t})")
        grid = threshold_grid(P(), cfg.num_thresholds)
        sw = sweep_stage(run_dir, P(), grid)
        ch = choose_threshold(sw, t)
        src = (
            f"criterion {t}: sweep of {len(grid)} ε from the connecting threshold to the "
            f"largest distance over these frames (r = {ch['score']:.4f})"
        )
        return ch["threshold"], src, sw, ch
    if t:
        return float(t), "value", None, None
    return cfg.threshold_factor * float(connecting_threshold(P())), (
        f"factor {cfg.threshold_factor:g} × connecting"
    ), None, None  # fmt: skip


def _space(P: Callable, eps: float) -> dict[str, Any]:
    t_conn = float(connecting_threshold(P()))
    if eps < t_conn:
        raise ConfigError(
            f"graph.threshold = {eps:.4g} leaves the graph disconnected; the smallest "
            f"connecting threshold is {t_conn:.4g}: raise it"
        )
    es = jax.block_until_ready(expression_space(None, eps, 2, pairwise=P()))
    return {
        "distances": es.geodesics.distances, "next_hop": es.geodesics.next_hop,
        "embedding": es.embedding, "score": es.score, "threshold": eps,
        "connecting_threshold": t_conn,
    }  # fmt: skip


def graph_kind(cfg: Config, n_frames: int) -> str:
    """``graph.kind``, or by size when unset: ``epsilon`` up to ``epsilon_max_frames``."""
    g = cfg.graph
    return g.kind or ("epsilon" if n_frames <= g.epsilon_max_frames else "knn")


def _fcm(hc: HierarchyConfig, kind: str, restarts: int | None = None) -> FuzzyCMeans:
    """The FCM solver of the ``[hierarchy]`` table: full memberships on the ε-graph,
    each frame's ``nearest`` centres on the k-NN graph."""
    kw = {"m": hc.m, "tol": hc.tol}
    r = hc.restarts if restarts is None else restarts
    if hc.max_steps > 0:
        kw["max_steps"] = hc.max_steps
    if r >= 0:
        kw["restarts"] = r
    return TruncatedFuzzyCMeans(nearest=hc.nearest, **kw) if kind == "knn" else FuzzyCMeans(**kw)


def build_levels(cfg: Config, Y, paths, seed: int, restarts: int | None = None,
                 kind: str | None = None) -> Hierarchy:  # fmt: skip
    """The FCM hierarchy of the config's ``[hierarchy]`` table (shared with the viewer)."""
    hc = cfg.hierarchy
    rule = LinkRule(rho=hc.rho_scale, bridges=hc.bridges,
                    sweep_max_centres=hc.link_sweep_max_centres,
                    max_centres=hc.max_link_centres or None)  # fmt: skip
    return build_hierarchy(
        Y, paths, c0=hc.c0, key=jax.random.PRNGKey(seed),
        fcm=_fcm(hc, kind or graph_kind(cfg, len(Y)), restarts), links=rule,
        levels=hc.levels or None, finest=hc.finest,
    )  # fmt: skip


def _knn_space(cfg: GraphConfig, positions, run_dir: Path | None = None) -> dict[str, Any]:
    """The k-NN graph of the frames' marker-distance features (a block at a time, here or
    on the config's Dask scheduler), landmark geodesics and the landmark MDS (memory
    O(T·k) besides the positions)."""
    X = np.asarray(positions, np.float64 if cfg.dtype == "float64" else np.float32)
    T = int(X.shape[0])
    # a remote cluster's workers write the features where they all reach: the run folder
    store = (run_dir / "cache" / "features.npy"
             if run_dir is not None and cfg.scheduler not in ("", "local") else None)  # fmt: skip
    if store is not None and store.is_file() and not store.is_symlink():
        store.unlink()  # our own, left by an interrupted run (anything else is refused)
    with dask_client(cfg.scheduler, cfg.workers) as client:
        g = neighbourhood_graph_blocks(X, k=cfg.k, store=store, client=client)
    if store is not None:
        store.unlink(missing_ok=True)
    try:
        check_sparse_connected(g)
    except FxspaceError as e:  # the user's fix is the config's k
        raise ConfigError(f"graph.k = {cfg.k}: {e}; raise graph.k") from e
    geo = farthest_point_landmarks(g, min(cfg.landmarks, T))
    mds = landmark_mds(geo, dim=2)
    return {
        "indices": np.asarray(g.indices), "weights": np.asarray(g.weights),
        "embedding": np.asarray(mds.embedding, np.float64),
        "score": float(landmark_score(geo, mds.embedding)),
    }  # fmt: skip


def _load_knn(cfg: Config, positions, run_dir: Path | None, seed: int) -> NavSpace:
    import jax.numpy as jnp

    T = int(np.shape(positions)[0])
    gc = cfg.graph
    stage(f"{T} frames: k-NN graph (k = {gc.k}), landmark geodesics, landmark MDS")
    sp = _stage(run_dir, "space", lambda: _knn_space(gc, positions, run_dir))
    g = NeighbourGraph(jnp.asarray(sp["indices"]), jnp.asarray(sp["weights"]))
    Y = np.asarray(sp["embedding"], np.float64)
    stage("fuzzy c-means levels and their links")
    ha = _stage(run_dir, "hierarchy", lambda: hierarchy_to_arrays(
        build_levels(cfg, Y, g, seed, kind="knn")))  # fmt: skip
    r = float(sp["score"])
    return NavSpace(Y, g, hierarchy_from_arrays(ha), float("nan"),
                    f"k-NN graph, k = {gc.k} (r = {r:.4f})", float("nan"), r, None, None,
                    "knn")  # fmt: skip


def load_space(cfg: Config, positions, run_dir: Path | None, seed: int) -> NavSpace:
    """The stages of ``positions`` for the config's graph kind (`graph_kind`) — ``sweep``
    → ``space`` → ``hierarchy`` on the ε-graph, ``space`` → ``hierarchy`` on the k-NN
    graph: each read from ``run_dir/cache`` when there, else computed (with progress)
    and stored; without a ``run_dir``, computed. The navigator app opens a finished run
    through this in seconds."""
    if graph_kind(cfg, int(np.shape(positions)[0])) == "knn":
        return _load_knn(cfg, positions, run_dir, seed)
    memo: dict[str, Any] = {}

    def P():
        if "P" not in memo:
            memo["P"] = state_distances(positions, cfg.graph.dtype)
        return memo["P"]

    eps, source, sw, ch = _threshold(cfg.graph, P, run_dir)
    stage(f"ε = {eps:.4g} ({source.split(':')[0]}): geodesics and 2-D embedding")
    sp = _stage(run_dir, "space", lambda: _space(P, eps))
    geo = Geodesics(sp["distances"], sp["next_hop"])
    Y = np.asarray(sp["embedding"])
    hc = cfg.hierarchy
    stage("fuzzy c-means levels and their links")
    ha = _stage(run_dir, "hierarchy", lambda: hierarchy_to_arrays(
        build_levels(cfg, Y, geo, seed, hc.restarts, kind="epsilon")))  # fmt: skip
    return NavSpace(
        Y, geo, hierarchy_from_arrays(ha), float(sp["threshold"]), source,
        float(sp["connecting_threshold"]), float(sp["score"]), sw, ch,
    )  # fmt: skip


def auto_key_centres(h: Hierarchy, paths, n: int, level: int = 0) -> list[int]:
    """``n`` key centres at ``level``, each linked to the previous: start at the centre
    geodesically farthest from the others on average, then repeatedly step to the linked,
    unvisited centre farthest (geodesically) from those already picked (``paths``: the
    frames' `Geodesics` or `NeighbourGraph`)."""
    lv = h.levels[level]
    cf = np.asarray(lv.center_frames)
    i, j = np.repeat(cf, len(cf)), np.tile(cf, len(cf))
    D = np.asarray(paths.lengths(i, j), np.float64).reshape(len(cf), len(cf))
    D = np.where(np.isfinite(D), D, 0.0)
    seq = [int(np.argmax(D.mean(axis=1)))]
    while len(seq) < n:
        nb = [int(k) for k in lv.neighbours(seq[-1]) if int(k) not in seq]
        if not nb:
            break
        seq.append(max(nb, key=lambda k: D[k, seq].min()))
    return seq


def prepare_app(cfg: Config, run_dir: Path, seed: int) -> None:
    """What the navigator shows, and only that (``fxspace studio CONFIG``): the run's own
    stages ``sweep`` → ``space`` → ``hierarchy`` (`load_space`), not its route, figures
    and animation (``fxspace run`` adds them, reusing the stages)."""
    cfg.validate()
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        face = load_face(cfg.data, seed)
        load_space(cfg, face.positions, Path(run_dir), seed)


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the navigation in ``graph.dtype`` (float64 turns on x64 for the run only)."""
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        return _run(cfg, Path(run_dir), seed)


def _run(cfg: Config, run_dir: Path, seed: int) -> dict:
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    stage(f"loading frames ({cfg.data.source})")
    face = load_face(cfg.data, seed)
    timings["load_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ns = load_space(cfg, face.positions, run_dir, seed)
    timings["space_and_hierarchy_s"] = time.perf_counter() - t0
    h, geo, Y = ns.hierarchy, ns.paths, ns.embedding

    nc = cfg.navigation
    keys = list(nc.key_centres) or auto_key_centres(h, geo, nc.num_keys)
    t0 = time.perf_counter()
    stage(f"{len(h.levels)} levels {list(h.sizes)}: route through key centres {keys}")
    try:
        routes = navigate(h, geo, keys)
    except FxspaceError as e:
        raise ConfigError(f"navigation.key_centres: {e}") from e
    timings["navigation_s"] = time.perf_counter() - t0
    play = playback(
        routes[-1].frames, Y, face.positions, fps=nc.fps, rate=face.rate,
        duration=nc.duration or None, by=nc.by,
    )  # fmt: skip
    t0 = time.perf_counter()
    crit = ns.choice["criterion"] if ns.choice else ns.threshold_source.split(" (")[0]
    note = (f"{ns.threshold:.4g} mm chosen by {crit}, r = {ns.r:.4f}" if ns.kind == "epsilon"
            else f"{len(Y)} frames, {ns.threshold_source}")  # fmt: skip
    anim = _write_outputs(cfg, run_dir, face, h, routes, play, keys, note)
    timings["figures_s"] = time.perf_counter() - t0
    W = ns.paths if ns.kind == "knn" else np.asarray(
        epsilon_graph(state_distances(face.positions, cfg.graph.dtype), ns.threshold))
    cold = None
    hc = cfg.hierarchy
    if hc.compare_cold and ns.kind == "epsilon":  # the warm start's benchmark: its own stage
        stage("cold starts of every warm-started level (compare_cold)")
        cold = cached(run_dir, "cold_levels", lambda: cold_levels(
            ns.embedding, c0=hc.c0, m=hc.m, key=jax.random.PRNGKey(seed), tol=hc.tol,
            max_steps=hc.max_steps if hc.max_steps > 0 else 300))  # fmt: skip
    return _metrics(cfg, face, ns, routes, play, keys, W, anim, timings, cold)


def _write_outputs(
    cfg: Config, run_dir: Path, face, h, routes, play, keys, eps_note: str = ""
) -> str | None:
    from fxspace.plot import (
        plot_level,
        plot_levels_grid,
        plot_link_radius_sweep,
        write_navigation_animation,
    )

    nc = cfg.navigation
    stage("figures" + (" and animation" if nc.animation != "none" else ""))
    if nc.level_figures and nc.figure:
        for li in progress(range(len(h.levels)), desc="level figures"):
            rt = next((rr for rr in routes if rr.level == li), None)
            save_figure_atomic(plot_level(h, li, rt), run_dir / f"level_{li:02d}.png")
    title = f"ε = {eps_note}" if eps_note else None
    if nc.figure:
        save_figure_atomic(plot_levels_grid(h, routes, title=title), run_dir / "levels_grid.png")
    if nc.figure and h.link_sweep is not None:
        save_figure_atomic(plot_link_radius_sweep(h.link_sweep, _chosen_scale(h)),
                           run_dir / "link_radius.png")  # fmt: skip
    anim = None
    if nc.figure and nc.animation != "none":
        anim = write_navigation_animation(
            run_dir / f"navigation.{nc.animation}", play, h.embedding, route=routes[0],
            names=face.marker_names, max_frames=nc.animation_frames,
            title=f"key centres {'-'.join(map(str, keys))} (level 0)",
        ).name  # fmt: skip
    final = routes[-1]
    save_npz_atomic(
        run_dir / "hierarchy.npz", embedding=h.embedding, sizes=np.asarray(h.sizes),
        final_frames=final.frames, playback_xy=play.xy, playback_frame=play.frame,
        **{f"centers_{i}": lv.centers for i, lv in enumerate(h.levels)},
        **{f"center_frames_{i}": lv.center_frames for i, lv in enumerate(h.levels)},
    )  # fmt: skip
    write_json_atomic(run_dir / "routes.json", [
        {"level": rt.level, "centres": list(rt.centres), "key_frames": rt.key_frames,
         "frames": rt.frames, "takes": face.take[rt.frames],
         "take_frames": face.frame[rt.frames]}
        for rt in routes
    ])  # fmt: skip
    return anim


def _level_metrics(lv, cold: dict | None = None) -> dict:
    if lv.init in ("kmeans++", "frames"):  # first / finest level: the run itself is cold
        cold = {"num_steps_cold": lv.num_steps, "objective_cold": lv.objective}
    cold = cold or {"num_steps_cold": -1, "objective_cold": float("nan")}
    return {
        "centres": lv.n_clusters,
        "init": lv.init,
        "iterations_warm": lv.num_steps,
        "iterations_split_start": lv.num_steps_split,
        "iterations_all_starts": lv.total_steps,
        "iterations_cold": cold["num_steps_cold"],
        "objective_warm": lv.objective,
        "objective_cold": cold["objective_cold"],
        "converged": lv.converged,
        # the FCM's outcome: "successful" at its fixed point, else why it stopped
        "result": repr(lv.result).removeprefix("RESULTS."),
        "result_message": result_message(lv.result),
        "distinct_centre_frames": int(len(np.unique(lv.center_frames))),
        "links": lv.n_links if lv.links is not None else None,
        "bridges": lv.n_bridges if lv.links is not None else None,
        "link_graph_connected": link_graph_connected(lv) if lv.links is not None else None,
        # groups of centres the links join (the rule alone can leave centres apart)
        "link_pieces": len(np.unique(link_components(lv))) if lv.links is not None else None,
        "radius": lv.radius,
    }


def _chosen_scale(h) -> float | None:
    """The ρ scale the experiment chose: each level's ρ over its centre spacing."""
    from fxspace.navigation import choose_link_scale

    return None if h.link_sweep is None else choose_link_scale(h.link_sweep)


def _rho_experiment(h) -> dict | None:
    """The ρ experiment's table for metrics.json (None when ρ was a fixed number)."""
    sw = h.link_sweep
    if sw is None:
        return None
    return {
        "scales": sw.scales.tolist(),
        "chosen_scale": _chosen_scale(h),
        "levels": [
            {"level": int(li), "centres": int(c), "links": sw.links[k].tolist(),
             "components": sw.components[k].tolist(),
             "coverage": [round(float(v), 6) for v in sw.coverage[k]]}
            for k, (li, c) in enumerate(zip(sw.levels, sw.centres, strict=True))
        ],
    }  # fmt: skip


def _metrics(cfg: Config, face, ns: NavSpace, routes, play, keys, W, anim, timings,
             cold: list | None = None) -> dict:  # fmt: skip
    h = ns.hierarchy
    levels = [_level_metrics(lv, None if cold is None else cold[i])
              for i, lv in enumerate(h.levels)]  # fmt: skip
    # the warm start's own cost: the split start alone, on the levels where it ran
    split = [lv for lv in levels if lv["iterations_split_start"] >= 0]
    warm = sum(lv["iterations_split_start"] for lv in split)
    cold = (sum(lv["iterations_cold"] for lv in split)
            if cfg.hierarchy.compare_cold and ns.kind == "epsilon" else None)  # fmt: skip
    final = routes[-1]
    sweep = None
    if ns.sweep is not None:
        sweep = [
            {"threshold": float(t), "r": float(r) if np.isfinite(r) else None}
            for t, r in zip(ns.sweep.thresholds, ns.sweep.scores, strict=True)
        ]
    return {
        "frames": int(len(ns.embedding)),
        "markers": int(face.positions.shape[1]),
        "takes": list(face.take_names),
        "missing": {
            "policy": cfg.data.missing,
            "max_gap": cfg.data.max_gap,
            **(face.missing or {}),
        },  # fmt: skip
        "reading": face.reading,  # what was read; every drop/resample/conversion said
        "threshold": ns.threshold,
        "threshold_source": ns.threshold_source,
        "criterion": ns.choice["criterion"] if ns.choice else None,
        "sweep": sweep,
        "connecting_threshold": ns.connecting_threshold,
        "r": ns.r,
        "num_levels": len(h.levels),
        "centres_per_level": list(h.sizes),
        "levels": levels,
        # links the paper's ρ rule forbids, added so that every route connects (bridges)
        "links_bridged": sum(lv["bridges"] or 0 for lv in levels),
        "graph_kind": ns.kind,
        # every level's FCM at its fixed point ("6/6"), and the reason where a cap stopped one
        "levels_converged": f"{sum(lv['converged'] for lv in levels)}/{len(levels)}",
        "fcm_not_converged": [
            {"level": i, "centres": lv["centres"], "result": lv["result"],
             "message": lv["result_message"], "iterations": lv["iterations_warm"]}
            for i, lv in enumerate(levels) if not lv["converged"]
        ],
        "link_pieces_finest": next(
            (lv["link_pieces"] for lv in reversed(levels) if lv["link_pieces"] is not None), None
        ),
        "rho_experiment": _rho_experiment(h),
        "iterations_split_start_total": warm,
        "iterations_cold_total": cold,
        "iterations_saved_by_warm_start": (cold - warm) if cold is not None else None,
        "iterations_all_starts_total": sum(lv["iterations_all_starts"] for lv in levels),
        "key_centres": keys,
        "route_centres_per_level": [len(rt.centres) for rt in routes],
        "path_length_frames": int(len(final.frames)),
        "path_is_graph_walk": is_graph_walk(final.frames, W),
        "playback_frames": int(len(play.times)),
        "playback_duration_s": float(play.times[-1]),
        "animation": anim,
        "timings": timings,
    }
