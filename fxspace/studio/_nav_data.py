"""What the navigator shows (`NavData`, `load_nav_data`: a navigation run's hierarchy,
paths and markers) and the small pieces its controller and view share: the route
operations on the data (`fxspace.navigation`'s), the undo snapshot and status helpers.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fxspace.navigation import (
    Hierarchy,
    Route,
    bridge_keys,
    is_sparse,
    make_route,
    path_candidates,
    refine_route,
    rigid_align,
)
from fxspace.results import result_message

__all__ = ["DENSITY_ABOVE", "NavData", "load_nav_data", "fcm_status", "Aligned", "InFace"]


DENSITY_ABOVE = 20_000
"""Above this many frames the pad draws their density, not one point per frame."""


@dataclass(frozen=True)
class NavData:
    """What the navigator shows: the hierarchy, the frames' paths, the markers, and where
    ε came from.

    ``paths`` is the frames' `Geodesics` (an ε-graph run) or their `NeighbourGraph` (a
    k-NN run, 10⁵ frames): routes are made, bridged and refined on either by the same
    `fxspace.navigation.make_route` & co."""

    hierarchy: Hierarchy
    paths: object
    positions: np.ndarray  # (T, M, 3)
    marker_names: tuple[str, ...] = ()
    rate: float = 60.0
    threshold: float = float("nan")
    threshold_source: str = ""
    joins: dict | None = None  # a k-NN graph's pieces and the edges joining them

    @property
    def geodesics(self):
        """The frames' paths (their old name)."""
        return self.paths

    @property
    def sparse(self) -> bool:
        """Whether the levels keep truncated memberships (a k-NN run)."""
        return is_sparse(self.hierarchy)


class _Routes:
    """The route operations on the data's hierarchy and paths: `fxspace.navigation`'s."""

    def __init__(self, data: NavData):
        self.d = data
        self.paths = data.paths

    def make(self, level: int, centres, anchors=None) -> Route:
        return make_route(self.d.hierarchy, self.paths, level, centres, anchors=anchors)

    def bridge(self, level: int, keys) -> tuple[list[int], list[str]]:
        return bridge_keys(self.d.hierarchy, self.paths, level, keys)

    def refine(self, route: Route) -> Route:
        return refine_route(self.d.hierarchy, self.paths, route)

    def candidates(self, level: int, frames) -> np.ndarray:
        return path_candidates(self.d.hierarchy, level, frames)


def load_nav_data(target: str | Path, *, restarts: int | None = None) -> NavData:
    """`NavData` of a navigation run folder or config file (``experiment = "navigation"``
    or ``"navigation_scale"``, either graph kind), opened through its pipeline's
    ``load_space``.

    A run folder's cached stages (``cache/sweep``, ``space``, ``hierarchy``; see
    `fxspace.pipelines.navigation.load_space`) are read, not recomputed — what a finished
    run holds opens in seconds; missing stages are computed and stored. A config file is
    computed without a cache. `restarts` overrides ``[hierarchy] restarts``.
    """
    import dataclasses

    from fxspace.datasets import load_face
    from fxspace.pipelines import resolve_config

    spec = resolve_config(target, experiment=("navigation", "navigation_scale"))[0]
    cfg, seed = spec.config, spec.seed
    if restarts is not None:
        cfg = dataclasses.replace(
            cfg, hierarchy=dataclasses.replace(cfg.hierarchy, restarts=int(restarts))
        )
    face = load_face(cfg.data, seed)
    run_dir = Path(target) if Path(target).is_dir() else None
    ns = spec.pipeline.load_space(cfg, face.positions, run_dir, seed)
    return NavData(
        ns.hierarchy, ns.paths, np.asarray(face.positions),
        tuple(face.marker_names), face.rate, ns.threshold, ns.threshold_source, ns.joins,
    )  # fmt: skip


class _State(NamedTuple):
    level: int
    picks: tuple[int, ...]
    route: Route | None
    guide: Route | None
    anchors: tuple[int, ...] | None
    message: str


def _short(a, n: int = 30) -> str:
    a = np.asarray(a)
    return ", ".join(map(str, a[:n].tolist())) + (" …" if len(a) > n else "")


def _bridge_count(lv) -> int:
    """Bridges of a level (none when not computed)."""
    return lv.n_bridges


def fcm_status(lv) -> str:
    """The level's FCM outcome for the status line: "" at its fixed point, else the
    reason it stopped (e.g. the iteration cap) and after how many iterations."""
    if lv.converged:
        return ""
    return (f"not at its fixed point — {repr(lv.result).removeprefix('RESULTS.')} after "
            f"{lv.num_steps} iterations: {result_message(lv.result)}")  # fmt: skip


class Aligned:
    """``[frame]``: that frame's markers rigidly aligned to the first frame
    (`fxspace.navigation.rigid_align`), computed when asked (a 10⁶-frame archive is not
    aligned up front); the last frame asked is kept, so the face and its markers drawn for
    one frame align it once. `in_face` gives them in the face's right/up/out frame."""

    def __init__(self, positions):
        self.positions = positions
        self._last: tuple[int, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, frame) -> np.ndarray:
        f = int(frame)
        if self._last is None or self._last[0] != f:
            X = rigid_align(np.asarray(self.positions[f])[None],
                            np.asarray(self.positions[0]))[0]  # fmt: skip
            self._last = (f, X)
        return self._last[1]

    def in_face(self, centre: np.ndarray, axes: np.ndarray) -> InFace:
        return InFace(self, centre, axes)


class InFace:
    """``[frame]``: an `Aligned` frame in the face's right/up/out frame."""

    def __init__(self, aligned: Aligned, centre: np.ndarray, axes: np.ndarray):
        self.aligned, self.centre, self.axes = aligned, centre, axes

    def __len__(self) -> int:
        return len(self.aligned)

    def __getitem__(self, frame) -> np.ndarray:
        return (self.aligned[frame] - self.centre) @ self.axes.T
