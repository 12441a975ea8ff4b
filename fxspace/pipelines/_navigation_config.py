"""The navigation experiment's configuration (`fxspace.pipelines.navigation`): the
``[graph]``, ``[hierarchy]`` and ``[navigation]`` tables, the graph kind they choose, and
`NavSpace`, what the cached stages give navigation and the navigator app."""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import numpy as np

from fxspace.config import ConfigError
from fxspace.datasets import FaceData
from fxspace.expression import Geodesics, NeighbourGraph, SweepResult
from fxspace.navigation import SWEEP_THRESHOLDS, THRESHOLD_CRITERIA, Hierarchy
from fxspace.pipelines._dask import check_stage_scheduler

GRAPH_KINDS = ("epsilon", "knn")


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
    (``tcp://HOST:PORT``; its workers must reach the run folder). The landmarks' rows
    run there too, ``landmark_batch`` of them a round (max-min in rounds,
    `fxspace.expression.farthest_point_landmarks`; 0: one after another, exact max-min,
    in this process). The graph, the landmarks, and so the whole run, are the same
    wherever they run.

    ``join`` (``knn``): a k-NN graph in pieces — several takes, each nearer itself than
    any other — is ``"closest"``: joined at the closest frames between pieces
    (`fxspace.expression.join_components`; the edges in the metrics' ``graph_joins``),
    or ``"none"``: refused, naming the pieces."""

    kind: str = ""
    threshold: float | str = "max_r"
    threshold_factor: float = 1.25
    num_thresholds: int = SWEEP_THRESHOLDS
    dtype: Literal["float32", "float64"] = "float32"
    k: int = 10
    landmarks: int = 256
    landmark_batch: int = 8
    epsilon_max_frames: int = 5000
    scheduler: str = ""
    workers: int = 2
    join: Literal["closest", "none"] = "closest"

    def validate(self) -> None:
        check_stage_scheduler(self.scheduler, self.workers)
        if self.join not in ("closest", "none"):
            raise ConfigError(f"graph.join must be 'closest' or 'none', got {self.join!r}")
        if self.kind not in ("", *GRAPH_KINDS):
            raise ConfigError(
                f"graph.kind must be one of {GRAPH_KINDS} (or unset), got {self.kind!r}"
            )
        if self.k < 2:
            raise ConfigError("graph.k must be >= 2 (neighbours per frame)")
        if self.landmarks < 3:
            raise ConfigError("graph.landmarks must be >= 3 (MDS in 2-D needs 3)")
        if self.landmark_batch < 0:
            raise ConfigError("graph.landmark_batch must be >= 0 (0: one landmark at a time)")
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
    (`fxspace.navigation.TruncatedFuzzyCMeans`), ``rows_per_task`` frames a block (each
    step's blocks run where the graph's blocks run, ``[graph] scheduler``; 0: one
    compiled loop in this process). ``max_steps`` / ``restarts``
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
    rows_per_task: int = 65536
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
        if self.rows_per_task < 0:
            raise ConfigError("hierarchy.rows_per_task must be >= 0 (0: one compiled loop)")
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
    where it came from (the k-NN graph's ``k`` there), the embedding's r; ``joins``: the
    edges that joined a k-NN graph's pieces (``graph.join``), None when it had one."""

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
    joins: dict | None = None

    @property
    def geodesics(self):
        """The frames' paths (the old name of `paths`)."""
        return self.paths


def graph_kind(cfg: Config, n_frames: int) -> str:
    """``graph.kind``, or by size when unset: ``epsilon`` up to ``epsilon_max_frames``."""
    g = cfg.graph
    return g.kind or ("epsilon" if n_frames <= g.epsilon_max_frames else "knn")
