"""The links' ρ by the paper's experiment (Kim & Jung §4.2: "the circle's radius is set
by experiment": `link_radius_sweep`, `choose_link_scale`) and every level's links by a
`LinkRule` (`_Linker`: level by level as a hierarchy's levels come, in a thread beside
their FCM, or one after another)."""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import Future
from typing import Any

import numpy as np

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.navigation._level import Hierarchy, Level, LinkRadiusSweep, _components
from fxspace.navigation._links import (
    LINK_SCALES,
    LinkRule,
    _clearances,
    default_link_radius,
    level_links,
    step_blocks,
)

__all__ = ["link_radius_sweep", "choose_link_scale"]


def _coverage(labels: np.ndarray) -> float:
    c = len(labels)
    if c < 2:
        return 1.0
    sizes = np.unique(labels, return_counts=True)[1].astype(np.float64)
    return float(np.sum(sizes * (sizes - 1)) / (c * (c - 1)))


@checked
def link_radius_sweep(
    hierarchy: Hierarchy,
    paths,
    scales=LINK_SCALES,
    *,
    max_centres: int | None = 320,
) -> LinkRadiusSweep:
    """Links by the paper's rule (no bridges, exact: one `link_clearance` pass per level)
    at each ρ of ``scales`` on every level with at most ``max_centres`` centres (and
    fewer centres than frames): how many links, how many groups they leave, and the
    fraction of centre pairs a route can join (Kim & Jung §4.2: "the circle's radius is
    set by experiment"); `choose_link_scale` reads the answer off it.

    **Example:** ``sw = fx.navigation.link_radius_sweep(h, space.geodesics)``
    """
    return _sweep(hierarchy, paths, scales, max_centres)[0]


def _scales(scales) -> np.ndarray:
    sc = np.asarray(scales, np.float64).reshape(-1)
    if not len(sc) or not np.all(np.isfinite(sc)) or np.any(sc < 0):
        raise FxspaceError(f"scales must be finite numbers >= 0, got {scales!r}")
    return sc


def _swept(sizes, T: int, max_centres) -> list[int]:
    """The levels the ρ experiment looks at: at most ``max_centres`` centres, fewer
    centres than frames (the first level always)."""
    idx = [i for i, c in enumerate(sizes)
           if (max_centres is None or c <= max_centres) and (c < T or i == 0)]  # fmt: skip
    if not idx:
        raise FxspaceError(f"no level has at most max_centres={max_centres} centres")
    return idx


def _sweep_level(x, paths, frames, sc: np.ndarray):
    """One level of the ρ experiment: ``(radii, links, pieces, coverage, (clear, D))``
    at each scale of ``sc``; one exact pass answers every ρ (linked at ρ ⇔ clearance ≥ ρ)."""
    radii = np.asarray([default_link_radius(x[frames], float(s)) for s in sc])
    clear, D = _clearances(x, paths, frames, float(np.min(radii)))
    links, comps, coverage = [], [], []
    for rho in radii:
        lk = clear >= rho
        np.fill_diagonal(lk, False)
        labels = _components(lk)
        links.append(int(lk.sum() // 2))
        comps.append(len(np.unique(labels)))
        coverage.append(_coverage(labels))
    return radii, links, comps, coverage, (clear, D)


def _sweep_table(sc, idx, sizes, rows) -> LinkRadiusSweep:
    """The `LinkRadiusSweep` of the swept levels' `_sweep_level` rows."""
    return LinkRadiusSweep(
        sc, np.asarray(idx), np.asarray(sizes),
        np.asarray([r[0] for r in rows]).reshape(len(idx), len(sc)),
        np.asarray([r[1] for r in rows], np.int64).reshape(len(idx), len(sc)),
        np.asarray([r[2] for r in rows], np.int64).reshape(len(idx), len(sc)),
        np.asarray([r[3] for r in rows], np.float64).reshape(len(idx), len(sc)),
    )  # fmt: skip


def _sweep(hierarchy, paths, scales, max_centres):
    """`link_radius_sweep` and the swept levels' ``{level: (clearances, distances)}``."""
    sc = _scales(scales)
    x = np.asarray(hierarchy.embedding)
    idx = _swept([lv.n_clusters for lv in hierarchy.levels], len(x), max_centres)
    rows = [_sweep_level(x, paths, hierarchy.levels[i].center_frames, sc) for i in idx]
    sizes = [hierarchy.levels[i].n_clusters for i in idx]
    return _sweep_table(sc, idx, sizes, rows), {i: r[4] for i, r in zip(idx, rows, strict=True)}


@checked
def choose_link_scale(sweep: LinkRadiusSweep) -> float:
    """The largest ρ scale of ``sweep`` at which every swept level stays in one piece
    (coverage 1): the widest circles, so the fewest links that pass by another centre,
    that still let every centre reach every other. When no scale joins every level, the
    largest scale with the best worst-level coverage (the levels left in pieces then
    need bridges, ``LinkRule(bridges=True)``, to route across them)."""
    worst = np.round(np.min(np.asarray(sweep.coverage), axis=0), 9)
    return float(sweep.scales[np.flatnonzero(worst == worst.max())[-1]])


_BACKGROUND_NICE = 10  # how much lower the finest level's early test runs (Linux)


def _background() -> None:
    """Lower this thread's CPU priority (Linux: the nice value is per thread, and the
    threads it starts, such as the k-d tree's workers, inherit it). The finest level's
    early test runs beside the FCM levels, whose steps wait on each other: at equal
    priority it slowed them by a third on two cores (measured: the navigation_scale
    prepare 35.1–35.5 s niced against 36.1–39.1 s not). No-op where it cannot be done."""
    if not sys.platform.startswith("linux"):  # elsewhere the id names a process
        return
    try:
        tid = threading.get_native_id()
        nice = os.getpriority(os.PRIO_PROCESS, tid) + _BACKGROUND_NICE
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError:  # not allowed: run as it is
        pass


def _finest_blocks(x, paths, scale: float, background: bool = False):
    """`step_blocks` of the level where every frame is a centre at ρ = ``scale`` × the
    frames' spacing (None where that is 0: its links then say why); ``background``: at a
    lower CPU priority (`_background`: its thread is its own, and ends with the build)."""
    if background:
        _background()
    rho = default_link_radius(x, scale)
    return step_blocks(x, paths, rho) if rho > 0 else None


class _Linker:
    """Every level's links by a `LinkRule`, level by level as the levels come (ρ by the
    experiment once its levels are all there), in order on ``pool`` (a one-thread
    executor) or here (``None``)."""

    def __init__(self, x, paths, rule: LinkRule, sizes, pool=None, pre_pool=None):
        self.x, self.paths, self.rule, self.pool = x, paths, rule, pool
        self.levels: list[Level] = []
        self.linked: list = []  # per level: its linked Level (or a future of it)
        self.rows: dict[int, Any] = {}  # swept level -> its experiment row (or future)
        self.scale: Any = None if rule.rho == "experiment" else float(rule.rho)
        self.sweep = None
        if self.scale is None:
            self.sc = _scales(rule.scales)
            self.idx = _swept(sizes, len(x), rule.sweep_max_centres)
        # the level where every frame is a centre needs no FCM: on ``pre_pool`` (a thread
        # of its own) its steps are tested at once, at the smallest ρ its scale can be
        # (blocked there, blocked at any larger ρ), while the FCM levels run and the other
        # levels are linked; its links then test only the steps left clear
        T = len(x)
        self.pre = None
        least = float(np.min(self.sc)) if self.scale is None else self.scale
        if (pre_pool is not None and T in sizes and least > 0
                and (rule.max_centres is None or T <= rule.max_centres)):  # fmt: skip
            self.pre = pre_pool.submit(_finest_blocks, x, paths, least, True)

    def _run(self, fn, *args):
        return fn(*args) if self.pool is None else self.pool.submit(fn, *args)

    @staticmethod
    def _get(v):
        return v.result() if isinstance(v, Future) else v

    def add(self, lv: Level) -> None:
        i = len(self.levels)
        self.levels.append(lv)
        if self.scale is None and i in self.idx:
            self.rows[i] = self._run(_sweep_level, self.x, self.paths, lv.center_frames, self.sc)
            if i == self.idx[-1]:  # the experiment's levels are all there: choose ρ
                self.scale = self._run(self._choose)
                self.linked += [self._run(self._link, j) for j in range(len(self.linked), i + 1)]
            return
        if self.scale is not None:
            self.linked += [self._run(self._link, j) for j in range(len(self.linked), i + 1)]

    def _choose(self) -> float:
        rows = [self._get(self.rows[i]) for i in self.idx]
        sizes = [self.levels[i].n_clusters for i in self.idx]
        self.sweep = _sweep_table(self.sc, self.idx, sizes, rows)
        return choose_link_scale(self.sweep)

    def _link(self, i: int) -> Level:
        lv, rule = self.levels[i], self.rule
        if rule.max_centres is not None and lv.n_clusters > rule.max_centres:
            return lv._replace(links=None, bridges=None, lengths=None, radius=float("nan"))
        rho = default_link_radius(self.x[lv.center_frames], float(self._get(self.scale)))
        clear, D = self._get(self.rows[i])[4] if i in self.rows else (None, None)
        pre = self._get(self.pre) if lv.n_clusters == len(self.x) and self.pre else None
        lk, br, ln = level_links(self.x, self.paths, lv.center_frames, rho, rule, clear, D,
                                 pre)  # fmt: skip
        return lv._replace(links=lk, bridges=br, lengths=ln, radius=rho)

    def hierarchy(self, embedding, link_sweep=None) -> Hierarchy:
        if self.scale is None:  # fewer levels than the experiment looks at: never happens
            raise FxspaceError("the ρ experiment's levels never all came")
        out = tuple(self._get(v) for v in self.linked)
        return Hierarchy(out, embedding, self.sweep if self.sweep is not None else link_sweep)


def _link_all(h: Hierarchy, paths, rule: LinkRule) -> Hierarchy:
    """Every level's links by ``rule`` (ρ by the experiment when it says so)."""
    x = np.asarray(h.embedding, np.float64)
    linker = _Linker(x, paths, rule, [lv.n_clusters for lv in h.levels])
    for lv in h.levels:
        linker.add(lv)
    return linker.hierarchy(h.embedding, h.link_sweep)
