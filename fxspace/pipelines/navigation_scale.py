"""Navigation at scale (issue 24; Kim & Jung §4 past 10⁴ frames): up to 100 000 frames,
sparse end to end.

The dense navigation (`fxspace.pipelines.navigation`) holds a ``T × T`` geodesic and
next-hop matrix and ``(c, c)`` links — about 2 400 frames is its scale. Here the same
chain runs on sparse structures: the frames' marker-distance features → a k-nearest-
neighbour graph (`fxspace.expression.neighbourhood_graph`, memory O(T·k)) → geodesics
from max-min landmarks and landmark MDS (the 2-D expression space; its r against the
landmark geodesics is reported) → fuzzy c-means levels with sparse memberships, their
links and the **finest level, where every frame is a centre**
(`fxspace.navigation.build_hierarchy` on the graph, ``finest=True``: links as
``csr_array``\\ s) →
a scripted route (key centres along links at level 0, refined level by level to frames,
`fxspace.navigation.navigate`). ``fxspace studio`` opens the run in the navigator
(the pad shows the frames' density past 20 000 frames).

Stages (`STAGES`, cached in ``run_dir/cache``; an interrupted run resumes and the
navigator reads them): ``space`` (the graph and the embedding) and ``hierarchy`` (the
levels, `fxspace.navigation.hierarchy_to_arrays`).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import stage
from fxspace.config import ConfigError
from fxspace.datasets import FaceData, load_face
from fxspace.errors import FxspaceError
from fxspace.expression import (
    NeighbourGraph,
    check_sparse_connected,
    distance_features,
    farthest_point_landmarks,
    landmark_mds,
    landmark_score,
    neighbourhood_graph,
    to_scipy,
)
from fxspace.navigation import (
    Hierarchy,
    SparseLevel,
    bridge_keys,
    build_hierarchy,
    hierarchy_from_arrays,
    hierarchy_to_arrays,
    navigate,
    playback,
)
from fxspace.runs import cached_arrays, save_figure_atomic, write_json_atomic

__all__ = [
    "Config",
    "GraphConfig",
    "HierarchyConfig",
    "NavConfig",
    "ScaleSpace",
    "STAGES",
    "prepare_app",
    "run",
    "load_scale_space",
    "auto_scale_keys",
]

STAGES = ("space", "hierarchy")


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """The sparse expression space: ``k`` nearest neighbours per frame (Euclidean, on the
    marker-distance features), ``landmarks`` max-min landmarks for the geodesics and the
    landmark MDS, in ``dtype``."""

    k: int = 10
    landmarks: int = 256
    dtype: Literal["float32", "float64"] = "float32"

    def validate(self) -> None:
        if self.k < 2:
            raise ConfigError("graph.k must be >= 2 (neighbours per frame)")
        if self.landmarks < 3:
            raise ConfigError("graph.landmarks must be >= 3 (MDS in 2-D needs 3)")


@dataclasses.dataclass(frozen=True)
class HierarchyConfig:
    """``levels`` FCM levels of c0·2^l centres (sparse memberships: ``nearest`` per frame),
    then, with ``finest``, the level where every frame is a centre."""

    c0: int = 10
    levels: int = 5
    nearest: int = 8
    finest: bool = True

    def validate(self) -> None:
        if self.c0 < 2 or self.levels < 1 or self.nearest < 1:
            raise ConfigError("hierarchy: need c0 >= 2, levels >= 1, nearest >= 1")


@dataclasses.dataclass(frozen=True)
class NavConfig:
    """Scripted route: ``key_centres`` at level 0 (empty: ``num_keys`` chosen along links),
    refined to the finest level, played at ``fps``."""

    key_centres: tuple[int, ...] = ()
    num_keys: int = 4
    fps: float = 30.0
    figure: bool = True

    def validate(self) -> None:
        if self.num_keys < 2 and not self.key_centres:
            raise ConfigError("navigation.num_keys must be >= 2")
        if not self.fps > 0:
            raise ConfigError("navigation.fps must be > 0")
        if any(k < 0 for k in self.key_centres):
            raise ConfigError("navigation.key_centres must be centre numbers >= 0")


@dataclasses.dataclass(frozen=True)
class Config:
    data: FaceData = FaceData(source="synthetic", synthetic_frames=20000)
    graph: GraphConfig = GraphConfig()
    hierarchy: HierarchyConfig = HierarchyConfig()
    navigation: NavConfig = NavConfig()

    def validate(self) -> None:
        for part in (self.graph, self.hierarchy, self.navigation):
            part.validate()


class ScaleSpace(NamedTuple):
    """What the navigation at scale (and the navigator) needs, from the cached stages."""

    graph: NeighbourGraph
    embedding: np.ndarray
    levels: list[SparseLevel]
    r: float

    @property
    def hierarchy(self) -> Hierarchy:
        """The levels and the embedding as a `fxspace.navigation.Hierarchy` (sparse levels)."""
        return Hierarchy(tuple(self.levels), self.embedding)


def _stage(run_dir: Path | None, name: str, compute) -> dict:
    if run_dir is None:
        return {k: np.asarray(v) for k, v in compute().items()}
    return cached_arrays(run_dir, name, compute)


def _space(cfg: GraphConfig, positions) -> dict[str, Any]:
    dt = jnp.float64 if cfg.dtype == "float64" else jnp.float32
    X = jnp.asarray(positions, dt)
    T = int(X.shape[0])
    F = jax.block_until_ready(jax.jit(distance_features)(X))
    g = neighbourhood_graph(F, k=cfg.k)
    jax.block_until_ready(g.weights)
    del F
    try:
        check_sparse_connected(g)
    except FxspaceError as e:  # the user's fix is the config's k
        raise ConfigError(f"graph.k = {cfg.k}: {e}; raise graph.k") from e
    geo = farthest_point_landmarks(g, min(cfg.landmarks, T))
    mds = landmark_mds(geo, dim=2)
    return {
        "indices": np.asarray(g.indices), "weights": np.asarray(g.weights),
        "embedding": np.asarray(mds.embedding, np.float64),
        "r": float(landmark_score(geo, mds.embedding)),
    }  # fmt: skip


def load_scale_space(cfg: Config, positions, run_dir: Path | None, seed: int) -> ScaleSpace:
    """The stages ``space`` → ``hierarchy`` of ``positions``: read from ``run_dir/cache``
    when there, else computed (with progress lines) and stored; without a ``run_dir``,
    computed."""
    T = int(np.shape(positions)[0])
    stage(f"{T} frames: k-NN graph (k = {cfg.graph.k}), landmark geodesics, landmark MDS")
    sp = _stage(run_dir, "space", lambda: _space(cfg.graph, positions))
    g = NeighbourGraph(jnp.asarray(sp["indices"]), jnp.asarray(sp["weights"]))
    Y = np.asarray(sp["embedding"], np.float64)
    hc = cfg.hierarchy
    stage(f"{hc.levels} FCM levels from c0 = {hc.c0}" + (" + every frame" if hc.finest else ""))

    def levels() -> dict:
        h = build_hierarchy(Y, g, levels=hc.levels, c0=hc.c0, key=jax.random.key(seed),
                            nearest=hc.nearest, finest=hc.finest)  # fmt: skip
        return hierarchy_to_arrays(h)

    ha = _stage(run_dir, "hierarchy", levels)
    return ScaleSpace(g, Y, list(hierarchy_from_arrays(ha).levels), float(sp["r"]))


def auto_scale_keys(levels, embedding, n: int, level: int = 0) -> list[int]:
    """``n`` key centres at ``level``, each linked to the previous: start at the centre
    farthest (2-D) from the others on average, then repeatedly step to the linked,
    unvisited centre farthest from those already picked (`auto_key_centres` of the dense
    navigation, in the embedding instead of the geodesics)."""
    lv = levels[level]
    c = np.asarray(embedding, np.float64)[np.asarray(lv.center_frames)]
    D = np.sqrt(np.sum((c[:, None] - c[None]) ** 2, axis=-1))
    seq = [int(np.argmax(D.mean(axis=1)))]
    while len(seq) < n:
        nb = [int(k) for k in lv.neighbours(seq[-1]) if int(k) not in seq]
        if not nb:
            break
        seq.append(max(nb, key=lambda k: D[k, seq].min()))
    return seq


def prepare_app(cfg: Config, run_dir: Path, seed: int) -> None:
    """What the navigator shows, and only that (``fxspace studio CONFIG``): the run's own
    stages ``space`` → ``hierarchy`` (`load_scale_space`), not its route and figure
    (``fxspace run`` adds them, reusing the stages)."""
    cfg.validate()
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        face = load_face(cfg.data, seed)
        load_scale_space(cfg, face.positions, Path(run_dir), seed)


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the navigation at scale in ``graph.dtype`` (float64: x64 for the run only)."""
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        return _run(cfg, Path(run_dir), seed)


def _run(cfg: Config, run_dir: Path, seed: int) -> dict:
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    stage(f"loading frames ({cfg.data.source})")
    face = load_face(cfg.data, seed)
    timings["load_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ss = load_scale_space(cfg, face.positions, run_dir, seed)
    timings["space_and_hierarchy_s"] = time.perf_counter() - t0
    g, Y, levels = ss.graph, ss.embedding, ss.levels
    nc = cfg.navigation
    keys = list(nc.key_centres) or auto_scale_keys(levels, Y, nc.num_keys)
    t0 = time.perf_counter()
    stage(f"{len(levels)} levels {[lv.n_clusters for lv in levels]}: route through {keys}")
    try:
        keys, notes = bridge_keys(ss.hierarchy, g, 0, keys)
        routes = navigate(ss.hierarchy, g, keys)
    except FxspaceError as e:  # a NavigationError names the centre
        raise ConfigError(f"navigation.key_centres: {e}") from e
    timings["navigation_s"] = time.perf_counter() - t0
    final = routes[-1]
    play = playback(final.frames, Y, face.positions, fps=nc.fps, rate=face.rate)
    csr = to_scipy(g)
    fr = np.asarray(final.frames)
    walk = bool(len(fr) < 2 or (np.all(fr[1:] != fr[:-1]) and np.all(csr[fr[:-1], fr[1:]] > 0)))
    write_json_atomic(run_dir / "routes.json", [
        {"level": rt.level, "centres": list(rt.centres), "key_frames": rt.key_frames,
         "frames": rt.frames}
        for rt in routes
    ])  # fmt: skip
    if nc.figure:
        from fxspace.plot import plot_levels_grid

        stage("figure: the levels and the route")
        save_figure_atomic(
            plot_levels_grid(ss.hierarchy, routes, title=f"{len(Y)} frames, r = {ss.r:.4f}"),
            run_dir / "levels_grid.png",
        )
    return {
        "frames": int(len(Y)),
        "markers": int(face.positions.shape[1]),
        "k": cfg.graph.k,
        "landmarks": min(cfg.graph.landmarks, len(Y)),
        "r_landmark": ss.r,
        "centres_per_level": [int(lv.n_clusters) for lv in levels],
        "links_per_level": [int(lv.links.nnz // 2) for lv in levels],
        "bridges_per_level": [int(lv.bridges.nnz // 2) for lv in levels],
        "key_centres": keys,
        "key_notes": notes,
        "route_centres_per_level": [len(rt.centres) for rt in routes],
        "path_length_frames": int(len(fr)),
        "path_is_graph_walk": walk,
        "playback_frames": int(len(play.times)),
        "timings": timings,
    }
