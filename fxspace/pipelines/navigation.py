"""Hierarchical navigation of the expression space (issue 3, Kim & Jung §4–5).

Loads facial frames (AnimFace takes or the synthetic face), builds the expression space
at ε taken from a finished threshold-sweep run (``threshold = "from:runs/threshold_sweep"``),
a criterion swept here (``"max_r"``, the seed paper's, ``"bounded_degree"``, ``"elbow"``),
an explicit value, or ``threshold_factor`` × the smallest connecting threshold (recorded
as ``threshold_source``),
builds the fuzzy c-means levels (warm-started, and cold for comparison), their links,
runs a scripted navigation (key centres at the first level refined automatically to the
finest) and writes the level figures, the grid of all levels, the animation, the
routes and the hierarchy.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Literal

import jax
import numpy as np

from fxspace._progress import progress, stage
from fxspace.config import ConfigError
from fxspace.datasets import FaceData, load_face
from fxspace.errors import FxspaceError
from fxspace.expression import pearson_score
from fxspace.navigation import navigation_space
from fxspace.navigation._hierarchy import Hierarchy, build_hierarchy
from fxspace.navigation._links import link_graph_connected
from fxspace.navigation._playback import playback
from fxspace.navigation._routes import is_graph_walk, navigate
from fxspace.navigation._space import THRESHOLD_CRITERIA
from fxspace.runs import save_figure_atomic, save_npz_atomic, write_json_atomic

__all__ = ["Config", "GraphConfig", "HierarchyConfig", "NavConfig", "run", "auto_key_centres"]


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """ε: ``threshold`` (same units as the features, mm); ``"from:RUN_DIR"`` — the ε a
    finished threshold-sweep run chose (one flow from the sweep to navigation); a criterion
    name (``"max_r"``, the seed paper's, ``"bounded_degree"``, ``"elbow"``) — a sweep here;
    or, when 0, ``threshold_factor`` × the smallest threshold that connects the graph.
    The metrics record which (``threshold_source``)."""

    threshold: float | str = 0.0
    threshold_factor: float = 1.25
    dtype: Literal["float32", "float64"] = "float32"

    def validate(self) -> None:
        if isinstance(self.threshold, str):
            if not (
                self.threshold.startswith("from:") or self.threshold in THRESHOLD_CRITERIA
            ):
                raise ConfigError(
                    f"graph.threshold must be a number, 'from:RUN_DIR' or one of "
                    f"{THRESHOLD_CRITERIA}; got {self.threshold!r}"
                )
            return
        if self.threshold < 0:
            raise ConfigError("graph.threshold must be >= 0 (0: use graph.threshold_factor)")
        if self.threshold == 0 and self.threshold_factor < 1.0:
            raise ConfigError(
                "graph.threshold_factor must be >= 1 (below 1 the graph is disconnected)"
            )


@dataclasses.dataclass(frozen=True)
class HierarchyConfig:
    """FCM levels c0·2^l (see :func:`fxspace.build_hierarchy`)."""

    c0: int = 10
    m: float = 2.0
    tol: float = 1e-4
    max_steps: int = 300
    restarts: int = 1
    rho_scale: float = 0.5
    compare_cold: bool = True
    max_link_centres: int = 0  # 0: links at every level

    def validate(self) -> None:
        if self.c0 < 1 or self.max_steps < 1 or not self.m > 1 or self.tol <= 0:
            raise ConfigError("hierarchy: need c0 >= 1, max_steps >= 1, m > 1, tol > 0")
        if self.rho_scale <= 0:
            raise ConfigError("hierarchy.rho_scale must be > 0")
        if self.restarts < 0:
            raise ConfigError("hierarchy.restarts must be >= 0")


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

    def validate(self) -> None:
        if self.num_keys < 2 and not self.key_centres:
            raise ConfigError("navigation.num_keys must be >= 2")
        if self.fps <= 0:
            raise ConfigError("navigation.fps must be > 0")


@dataclasses.dataclass(frozen=True)
class Config:
    data: FaceData = FaceData(max_frames=2400)
    graph: GraphConfig = GraphConfig()
    hierarchy: HierarchyConfig = HierarchyConfig()
    navigation: NavConfig = NavConfig()


def auto_key_centres(h: Hierarchy, geodesics, n: int, level: int = 0) -> list[int]:
    """``n`` key centres at ``level``, each linked to the previous: start at the centre
    geodesically farthest from the others on average, then repeatedly step to the linked,
    unvisited centre farthest (geodesically) from those already picked."""
    lv = h.levels[level]
    D = np.asarray(geodesics.distances, np.float64)[np.ix_(lv.center_frames, lv.center_frames)]
    D = np.where(np.isfinite(D), D, 0.0)
    seq = [int(np.argmax(D.mean(axis=1)))]
    while len(seq) < n:
        nb = [int(k) for k in lv.neighbours(seq[-1]) if int(k) not in seq]
        if not nb:
            break
        seq.append(max(nb, key=lambda k: D[k, seq].min()))
    return seq


def build_space(cfg: Config, face):
    """ε-graph, geodesics and 2-D MDS of the frames as the config says (library wiring).

    Returns ``(P, W, geodesics, mds, connecting_threshold, ε, source)``; raises
    ``ConfigError`` when the configured ε leaves the graph disconnected.
    """
    try:
        ns = navigation_space(
            face.positions,
            cfg.graph.threshold or None,
            threshold_factor=cfg.graph.threshold_factor,
            dtype=cfg.graph.dtype,
            hierarchy=None,
        )
    except FxspaceError as e:
        raise ConfigError(f"graph: {e}") from e
    es = ns.space
    return (
        es.pairwise, es.graph, es.geodesics, es.mds, ns.connecting_threshold, ns.threshold,
        ns.threshold_source,
    )  # fmt: skip


def build_levels(cfg: Config, Y, geo, seed: int, restarts: int, compare_cold: bool = False):
    """The FCM hierarchy of the config's ``[hierarchy]`` table (shared with the viewer)."""
    hc = cfg.hierarchy
    return build_hierarchy(
        Y,
        geo,
        c0=hc.c0,
        m=hc.m,
        key=jax.random.PRNGKey(seed),
        tol=hc.tol,
        max_steps=hc.max_steps,
        warm_start=True,
        restarts=restarts,
        compare_cold=compare_cold,
        rho_scale=hc.rho_scale,
        max_link_centres=hc.max_link_centres or None,
    )


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    from fxspace.plot import plot_level, plot_levels_grid, write_navigation_animation

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    stage(f"loading frames ({cfg.data.source})")
    face = load_face(cfg.data, seed)
    timings["load_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage(
        f"{len(face.positions)} frames × {face.positions.shape[1]} markers: "
        "graph, geodesics and 2-D embedding"
    )
    P, W, geo, mds, t_conn, eps, eps_source = build_space(cfg, face)
    r = float(pearson_score(geo.distances, mds.embedding))
    timings["expression_space_s"] = time.perf_counter() - t0
    Y = np.asarray(mds.embedding)

    hc = cfg.hierarchy
    t0 = time.perf_counter()
    stage(f"ε = {eps:.4g} ({eps_source}): fuzzy c-means levels and their links")
    h = build_levels(cfg, Y, geo, seed, restarts=hc.restarts, compare_cold=hc.compare_cold)
    timings["hierarchy_s"] = time.perf_counter() - t0

    nc = cfg.navigation
    keys = list(nc.key_centres) or auto_key_centres(h, geo, nc.num_keys)
    t0 = time.perf_counter()
    stage(f"{len(h.levels)} levels {list(h.sizes)}: route through key centres {keys}")
    routes = navigate(h, geo, keys)
    timings["navigation_s"] = time.perf_counter() - t0
    final = routes[-1]
    Wn = np.asarray(W)
    play = playback(
        final.frames,
        Y,
        face.positions,
        fps=nc.fps,
        rate=face.rate,
        duration=nc.duration or None,
        by=nc.by,
    )

    t0 = time.perf_counter()
    stage("figures" + (" and animation" if nc.animation != "none" else ""))
    if nc.level_figures:
        for li in progress(range(len(h.levels)), desc="level figures"):
            rt = next((rr for rr in routes if rr.level == li), None)
            save_figure_atomic(plot_level(h, li, rt), run_dir / f"level_{li:02d}.png")
    save_figure_atomic(plot_levels_grid(h, routes), run_dir / "levels_grid.png")
    timings["figures_s"] = time.perf_counter() - t0
    anim_path = None
    if nc.animation != "none":
        t0 = time.perf_counter()
        anim_path = write_navigation_animation(
            run_dir / f"navigation.{nc.animation}",
            play,
            Y,
            route=routes[0],
            names=face.marker_names,
            max_frames=nc.animation_frames,
            title=f"key centres {'-'.join(map(str, keys))} (level 0)",
        )
        timings["animation_s"] = time.perf_counter() - t0

    save_npz_atomic(
        run_dir / "hierarchy.npz",
        embedding=Y,
        sizes=np.asarray(h.sizes),
        final_frames=final.frames,
        playback_xy=play.xy,
        playback_frame=play.frame,
        **{f"centers_{i}": lv.centers for i, lv in enumerate(h.levels)},
        **{f"center_frames_{i}": lv.center_frames for i, lv in enumerate(h.levels)},
    )
    write_json_atomic(
        run_dir / "routes.json",
        [
            {
                "level": rt.level,
                "centres": list(rt.centres),
                "key_frames": rt.key_frames,
                "frames": rt.frames,
                "takes": face.take[rt.frames],
                "take_frames": face.frame[rt.frames],
            }
            for rt in routes
        ],
    )

    levels = []
    for lv in h.levels:
        levels.append(
            {
                "centres": lv.n_clusters,
                "init": lv.init,
                "iterations_warm": lv.num_steps,
                "iterations_split_start": lv.num_steps_split,
                "iterations_all_starts": lv.total_steps,
                "iterations_cold": lv.num_steps_cold,
                "objective_warm": lv.objective,
                "objective_cold": lv.objective_cold,
                "converged": lv.converged,
                "distinct_centre_frames": int(len(np.unique(lv.center_frames))),
                "links": int(lv.links.sum() // 2) if lv.links is not None else None,
                "bridges": int(lv.bridges.sum() // 2) if lv.bridges is not None else None,
                "link_graph_connected": (
                    link_graph_connected(lv) if lv.links is not None else None
                ),
                "radius": lv.radius,
                "fcm_time_s": lv.time_s,
            }
        )
    # the warm start's own cost: the split start alone, on the levels where it ran
    split = [lv for lv in levels if lv["iterations_split_start"] >= 0]
    warm = sum(lv["iterations_split_start"] for lv in split)
    cold = sum(lv["iterations_cold"] for lv in split) if hc.compare_cold else None
    return {
        "frames": int(len(Y)),
        "markers": int(face.positions.shape[1]),
        "takes": list(face.take_names),
        "missing": {
            "policy": cfg.data.missing,
            "max_gap": cfg.data.max_gap,
            **(face.missing or {}),
        },
        "threshold": eps,
        "threshold_source": eps_source,
        "connecting_threshold": t_conn,
        "r": r,
        "num_levels": len(h.levels),
        "centres_per_level": list(h.sizes),
        "levels": levels,
        "iterations_split_start_total": warm,
        "iterations_cold_total": cold,
        "iterations_saved_by_warm_start": (cold - warm) if cold is not None else None,
        "iterations_all_starts_total": sum(lv["iterations_all_starts"] for lv in levels),
        "key_centres": keys,
        "route_centres_per_level": [len(rt.centres) for rt in routes],
        "path_length_frames": int(len(final.frames)),
        "path_is_graph_walk": is_graph_walk(final.frames, Wn),
        "playback_frames": int(len(play.times)),
        "playback_duration_s": float(play.times[-1]),
        "animation": anim_path.name if anim_path is not None else None,
        "timings": timings,
    }
