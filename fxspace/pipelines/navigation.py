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

import contextlib
import hashlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from fxspace._progress import stage
from fxspace.config import ConfigError
from fxspace.datasets import load_face
from fxspace.errors import FxspaceError
from fxspace.expression import (
    Geodesics,
    NeighbourGraph,
    check_sparse_connected,
    connecting_threshold,
    epsilon_graph,
    expression_space,
    farthest_point_landmarks,
    join_components,
    landmark_mds,
    landmark_score,
    neighbourhood_graph_blocks,
)
from fxspace.navigation import (
    FuzzyCMeans,
    Hierarchy,
    LinkRule,
    TruncatedFuzzyCMeans,
    build_hierarchy,
    cold_levels,
    hierarchy_from_arrays,
    hierarchy_to_arrays,
    navigate,
    playback,
)
from fxspace.pipelines._dask import dask_client
from fxspace.pipelines._navigation_config import GRAPH_KINDS as GRAPH_KINDS
from fxspace.pipelines._navigation_config import Config as Config
from fxspace.pipelines._navigation_config import GraphConfig as GraphConfig
from fxspace.pipelines._navigation_config import HierarchyConfig as HierarchyConfig
from fxspace.pipelines._navigation_config import NavConfig as NavConfig
from fxspace.pipelines._navigation_config import NavSpace as NavSpace
from fxspace.pipelines._navigation_config import graph_kind as graph_kind
from fxspace.pipelines._navigation_outputs import _chosen_scale as _chosen_scale
from fxspace.pipelines._navigation_outputs import _level_metrics as _level_metrics
from fxspace.pipelines._navigation_outputs import _metrics as _metrics
from fxspace.pipelines._navigation_outputs import _rho_experiment as _rho_experiment
from fxspace.pipelines._navigation_outputs import _write_outputs as _write_outputs
from fxspace.pipelines._navigation_threshold import _threshold as _threshold
from fxspace.pipelines._navigation_threshold import threshold_from_run as threshold_from_run
from fxspace.pipelines.threshold_sweep import state_distances
from fxspace.runs import cached, cached_arrays

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
    "threshold_from_run",
]


STAGES = ("sweep", "space", "hierarchy", "cold_levels")
APP = "fxspace.studio._navigator:serve"  # `fxspace studio` of a run: the navigator
REPRODUCTION = "kim-jung"  # its reproduction page (`fxspace docs`)


_LAST_P: list = []  # [(key, P)]: the last frames' state distances, held for this process


def _distances(positions, dtype: str):
    """`state_distances` of ``positions``, kept for the last frames: ``fxspace studio
    CONFIG`` prepares the stages and then opens the app in one process, and the app's
    ε needs the same distances again (as does a run's ε-graph)."""
    a = np.ascontiguousarray(positions)
    if len(a) > _KEEP_P_FRAMES:  # (T, T): not held past the call
        return state_distances(a, dtype)
    key = (a.shape, str(a.dtype), dtype, hashlib.sha1(a.tobytes()).hexdigest())
    if not _LAST_P or _LAST_P[0][0] != key:
        _LAST_P[:] = [(key, state_distances(a, dtype))]
    return _LAST_P[0][1]


_KEEP_P_FRAMES = 4096  # 64 MiB of float32 distances at most


def _stage(run_dir: Path | None, name: str, compute: Callable[[], dict]) -> dict:
    if run_dir is None:
        return {k: np.asarray(v) for k, v in compute().items()}
    return cached_arrays(run_dir, name, compute)


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


def _fcm(hc: HierarchyConfig, kind: str, restarts: int | None = None,
         client=None) -> FuzzyCMeans:  # fmt: skip
    """The FCM solver of the ``[hierarchy]`` table: full memberships on the ε-graph,
    each frame's ``nearest`` centres on the k-NN graph (a block of ``rows_per_task``
    frames a task, on ``client`` when given)."""
    kw = {"m": hc.m, "tol": hc.tol}
    r = hc.restarts if restarts is None else restarts
    if hc.max_steps > 0:
        kw["max_steps"] = hc.max_steps
    if r >= 0:
        kw["restarts"] = r
    if kind != "knn":
        return FuzzyCMeans(**kw)
    if hc.rows_per_task:
        kw.update(rows_per_task=hc.rows_per_task, client=client)
    return TruncatedFuzzyCMeans(nearest=hc.nearest, **kw)


def build_levels(cfg: Config, Y, paths, seed: int, restarts: int | None = None,
                 kind: str | None = None, client=None) -> Hierarchy:  # fmt: skip
    """The FCM hierarchy of the config's ``[hierarchy]`` table (shared with the viewer);
    ``client``: the Dask client the k-NN graph's FCM blocks run on (None: here)."""
    hc = cfg.hierarchy
    rule = LinkRule(rho=hc.rho_scale, bridges=hc.bridges,
                    sweep_max_centres=hc.link_sweep_max_centres,
                    max_centres=hc.max_link_centres or None)  # fmt: skip
    return build_hierarchy(
        Y, paths, c0=hc.c0, key=jax.random.PRNGKey(seed),
        fcm=_fcm(hc, kind or graph_kind(cfg, len(Y)), restarts, client), links=rule,
        levels=hc.levels or None, finest=hc.finest,
    )  # fmt: skip


def _knn_space(cfg: GraphConfig, positions, run_dir: Path | None, client) -> dict[str, Any]:
    """The k-NN graph of the frames' marker-distance features (a block at a time, here or
    on the Dask ``client``), landmark geodesics and the landmark MDS (memory O(T·k)
    besides the positions)."""
    X = np.asarray(positions, np.float64 if cfg.dtype == "float64" else np.float32)
    T = int(X.shape[0])
    # a remote cluster's workers write the features where they all reach: the run folder
    store = (run_dir / "cache" / "features.npy"
             if run_dir is not None and cfg.scheduler not in ("", "local") else None)  # fmt: skip
    if store is not None and store.is_file() and not store.is_symlink():
        store.unlink()  # our own, left by an interrupted run (anything else is refused)
    g = neighbourhood_graph_blocks(X, k=cfg.k, store=store, client=client)
    if store is not None:
        store.unlink(missing_ok=True)
    try:
        if cfg.join == "closest":
            g, joins = join_components(g, X)
        else:
            check_sparse_connected(g)
            joins = None
    except FxspaceError as e:  # the user's fix is the config's k (or its join)
        fix = "raise graph.k" + ("" if cfg.join == "closest" else
                                 ', or set graph.join = "closest" to join the pieces')  # fmt: skip
        raise ConfigError(f"graph.k = {cfg.k}: {e}; {fix}") from e
    if joins is not None and len(joins.lengths):
        lengths = np.round(joins.lengths, 3).tolist()[:10]
        stage(f"the k-NN graph was in {len(joins.sizes)} pieces (sizes "
              f"{joins.sizes.tolist()[:10]}): joined at their closest frames by "
              f"{len(joins.lengths)} edges (lengths {lengths})")  # fmt: skip
    out_joins = ({} if joins is None else
                 {"join_frames": joins.frames, "join_lengths": joins.lengths,
                  "join_sizes": joins.sizes})  # fmt: skip
    # max-min in rounds: each round's rows as tasks where the graph's blocks ran
    batch = cfg.landmark_batch or None
    geo = farthest_point_landmarks(g, min(cfg.landmarks, T), batch=batch,
                                   client=client if batch else None)  # fmt: skip
    mds = landmark_mds(geo, dim=2)
    return {
        "indices": np.asarray(g.indices), "weights": np.asarray(g.weights),
        "embedding": np.asarray(mds.embedding, np.float64),
        "score": float(landmark_score(geo, mds.embedding)), **out_joins,
    }  # fmt: skip


def _load_knn(cfg: Config, positions, run_dir: Path | None, seed: int) -> NavSpace:
    import jax.numpy as jnp

    T = int(np.shape(positions)[0])
    gc = cfg.graph
    with contextlib.ExitStack() as stack:
        held: list = []

        def client():  # started only for a stage that is computed, once for both
            if not held:
                held.append(stack.enter_context(dask_client(gc.scheduler, gc.workers)))
            return held[0]

        stage(f"{T} frames: k-NN graph (k = {gc.k}), landmark geodesics, landmark MDS")
        sp = _stage(run_dir, "space", lambda: _knn_space(gc, positions, run_dir, client()))
        g = NeighbourGraph(jnp.asarray(sp["indices"]), jnp.asarray(sp["weights"]))
        Y = np.asarray(sp["embedding"], np.float64)
        stage("fuzzy c-means levels and their links")
        ha = _stage(run_dir, "hierarchy", lambda: hierarchy_to_arrays(
            build_levels(cfg, Y, g, seed, kind="knn", client=client())))  # fmt: skip
    r = float(sp["score"])
    joins = None
    if len(sp.get("join_lengths", ())):
        joins = {"pieces": np.asarray(sp["join_sizes"]).tolist(),
                 "frames": np.asarray(sp["join_frames"]).tolist(),
                 "lengths": np.asarray(sp["join_lengths"]).tolist()}  # fmt: skip
    joined = f", {len(joins['pieces'])} pieces joined" if joins else ""
    return NavSpace(Y, g, hierarchy_from_arrays(ha), float("nan"),
                    f"k-NN graph, k = {gc.k}{joined} (r = {r:.4f})", float("nan"), r, None,
                    None, "knn", joins)  # fmt: skip


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
            memo["P"] = _distances(positions, cfg.graph.dtype)
        return memo["P"]

    eps, source, sw, ch = _threshold(cfg.graph, P, run_dir)
    stage(f"ε = {eps:.4g} ({source.split(' (')[0]}): geodesics and 2-D embedding")
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
        epsilon_graph(_distances(face.positions, cfg.graph.dtype), ns.threshold))
    cold = None
    hc = cfg.hierarchy
    if hc.compare_cold and ns.kind == "epsilon":  # the warm start's benchmark: its own stage
        stage("cold starts of every warm-started level (compare_cold)")
        cold = cached(run_dir, "cold_levels", lambda: cold_levels(
            ns.embedding, c0=hc.c0, m=hc.m, key=jax.random.PRNGKey(seed), tol=hc.tol,
            max_steps=hc.max_steps if hc.max_steps > 0 else 300))  # fmt: skip
    return _metrics(cfg, face, ns, routes, play, keys, W, anim, timings, cold)
