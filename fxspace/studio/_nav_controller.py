"""The navigator's state and actions (Kim & Jung §3.5–3.6), independent of any UI.

*Look, then choose*: a click anywhere on the 2-D pad *previews* the nearest centre of the
shown level (its face is shown; nothing is committed), through a grid index, so the finest
level with thousands of centres stays responsive. An explicit action then edits the key
centres in place, at any level: `commit` (append the previewed centre), `insert_key`
(between two keys), `replace_key`, `delete_key`; the route is recomputed and kept valid —
consecutive keys linked, or bridged along the shortest chain of links with a note
(`fxspace.navigation.bridge_keys`). The animator also jumps to any level (`level_up`,
`level_down`), re-picks near the current route (the *candidates*; by default picks at a
finer level are held to them), refines automatically, goes back (undo across levels),
plays and exports the route.

Changing level keeps the route: it becomes the *guide* whose candidates are shown at the
new level, and the route picked there replaces it as the shown route.

Past `DENSITY_ABOVE` frames the pad shows the frames as a density image (a 2-D
histogram of the embedding, one texture) instead of one point per frame
(`NavigatorController.pad_mode`); centres, links and the route are drawn on top.
"""

from __future__ import annotations

import threading
from typing import Literal

import numpy as np

from fxspace.navigation import GridIndex, NavigationError, Route
from fxspace.studio._nav_data import (
    DENSITY_ABOVE,
    NavData,
    _bridge_count,
    _Routes,
    _short,
    _State,
    fcm_status,
    load_nav_data,
)
from fxspace.studio._nav_playback import _RoutePlayback
from fxspace.studio._server import FrameDensity, frame_density

__all__ = ["DENSITY_ABOVE", "NavData", "NavigatorController", "load_nav_data"]


class NavigatorController(_RoutePlayback):
    """The navigator's state and actions.

    ``level`` is the level shown; ``picks`` the key centres picked there; ``route`` the
    route shown (built from ``picks``, or the route kept from another level); ``guide``
    the route the current picks refine (its candidates are shown); ``restrict`` holds
    finer-level picks to the candidates; ``loop`` replays the route; ``message`` the
    last status or error line. ``pad_mode`` says how the pad shows the frames:
    ``"points"`` (one per frame) up to ``density_above`` frames, else ``"density"`` (a
    ``density_bins × density_bins`` histogram, `frame_density`).
    """

    def __init__(
        self,
        data: NavData,
        *,
        restrict: bool = True,
        loop: bool = True,
        density_above: int = DENSITY_ABOVE,
        density_bins: int = 256,
    ):
        self.data = data
        self.routes = _Routes(data)
        self._cand: dict = {}  # (level, id(frames)) → (frames, candidates), recent asks
        self.density_above = int(density_above)
        self.density_bins = int(density_bins)
        self._density: FrameDensity | None = None
        self.level = 0
        self.picks: list[int] = []
        self.route: Route | None = None
        self.guide: Route | None = None
        self.anchors: tuple[int, ...] | None = None
        self.restrict = restrict
        self.loop = loop
        self.message = "click the pad (or type a centre's number) to pick the first key centre"
        self.selected_frame = int(data.hierarchy.levels[0].center_frames[0])
        self.play_index = 0
        self.playing = False
        self.last_click: np.ndarray | None = None
        self.preview: int | None = None  # the centre looked at, not committed
        self.selected_key = 0  # the key position that insert/replace/delete act on
        self._play = None
        self._history: list[_State] = []
        self._index: dict[int, GridIndex] = {}
        self._lock = threading.RLock()

    # -- state ---------------------------------------------------------------------------
    @property
    def n_levels(self) -> int:
        return len(self.data.hierarchy.levels)

    @property
    def n_frames(self) -> int:
        return len(self.data.hierarchy.embedding)

    @property
    def pad_mode(self) -> Literal["points", "density"]:
        """How the pad shows the frames: one point each, or their density."""
        return "density" if self.n_frames > self.density_above else "points"

    @property
    def centres_by_density(self) -> bool:
        """True when the shown level has more than ``density_above`` centres (the finest
        levels, where centres are nearly the frames): the pad then shows them through the
        frames' density, without a point per centre nor links; clicks still pick the
        nearest centre."""
        return self.data.hierarchy.levels[self.level].n_clusters > self.density_above

    def frame_density(self) -> FrameDensity:
        """The frames' 2-D histogram on the pad (computed once): ``counts`` is
        ``(density_bins, density_bins)``, row i the i-th band of y, column j of x."""
        if self._density is None:
            self._density = frame_density(self.data.hierarchy.embedding, self.density_bins)
        return self._density

    def _snapshot(self) -> _State:
        return _State(
            self.level, tuple(self.picks), self.route, self.guide, self.anchors, self.message
        )

    def _push(self) -> None:
        self._history.append(self._snapshot())

    def _restore(self, s: _State) -> None:
        self.level, self.picks, self.route = s.level, list(s.picks), s.route
        self.guide, self.anchors = s.guide, s.anchors
        self._play = None
        self.play_index = 0

    def _rebuild(self) -> None:
        self._play = None
        self.play_index = 0
        if self.picks:
            self.route = self.routes.make(self.level, self.picks, self.anchors)
        else:
            self.route = self.guide

    def index(self, level: int | None = None) -> GridIndex:
        """The spatial index of the centres of ``level`` (built once per level)."""
        lv = self.level if level is None else int(level)
        if lv not in self._index:
            h = self.data.hierarchy
            self._index[lv] = GridIndex(h.embedding[h.levels[lv].center_frames])
        return self._index[lv]

    # -- actions -------------------------------------------------------------------------
    def set_level(self, level: int) -> None:
        """Jump to any level; the route is kept (it guides the picks there)."""
        with self._lock:
            level = int(level)
            if not 0 <= level < self.n_levels:
                raise NavigationError(f"level must be in [0, {self.n_levels - 1}]")
            if level == self.level:
                return
            self._push()
            self.guide = self.route
            self.level = level
            self.picks = []
            self.anchors = None
            self.preview = None
            self._rebuild()
            n = len(self.candidates())
            self.message = f"level {level}: pick key centres" + (
                f" ({n} candidates near the route)" if self.guide is not None else ""
            )

    def _restricted(self) -> bool:
        return self.restrict and self.guide is not None and self.level > self.guide.level

    def pick(self, centre: int) -> bool:
        """Append ``centre`` to the key centres; False (and a message) if not allowed."""
        with self._lock:
            lv = self.data.hierarchy.levels[self.level]
            centre = int(centre)
            if not 0 <= centre < lv.n_clusters:
                self.message = f"centre {centre} does not exist at level {self.level}"
                return False
            if self._restricted():
                cand = self.candidates()
                if centre not in set(cand.tolist()):
                    self.message = (
                        f"not picked: centre {centre} is not near the route of level "
                        f"{self.guide.level} (candidates: {_short(cand)}); untick "  # type: ignore[union-attr]
                        "'Restrict to candidates' to pick freely"
                    )
                    return False
            try:
                self.routes.make(self.level, [*self.picks[-1:], centre])
            except NavigationError as e:
                self.message = f"not picked: {e}"
                return False
            self._push()
            self.picks.append(centre)
            self.selected_frame = int(lv.center_frames[centre])
            self._rebuild()
            self.message = f"picked centre {centre} (frame {self.selected_frame})"
            return True

    def nearest_centre(self, xy) -> int:
        """The centre of the shown level nearest the 2-D point ``xy``; while picks are held
        to the candidates, the nearest candidate."""
        if self._restricted():
            cand = self.candidates()
            if len(cand):
                h = self.data.hierarchy
                p = h.embedding[h.levels[self.level].center_frames[cand]]
                return int(cand[np.argmin(np.sum((p - np.asarray(xy)) ** 2, axis=1))])
        return self.index().nearest(xy)

    def pick_at(self, xy) -> tuple[int, bool]:
        """A click on the pad at expression-space point ``xy``: pick the nearest centre."""
        with self._lock:
            self.last_click = np.asarray(xy, np.float64)
            k = self.nearest_centre(xy)
            return k, self.pick(k)

    # -- look, then choose -----------------------------------------------------------------
    def preview_centre(self, centre: int) -> int:
        """Show centre ``centre`` of the shown level (its face) without committing it."""
        with self._lock:
            lv = self.data.hierarchy.levels[self.level]
            centre = int(centre)
            if not 0 <= centre < lv.n_clusters:
                raise NavigationError(
                    f"centre {centre} does not exist at level {self.level} "
                    f"(it has {lv.n_clusters} centres)"
                )
            self.preview = centre
            self.selected_frame = int(lv.center_frames[centre])
            self.message = (
                f"previewing centre {centre} (frame {self.selected_frame}): Commit adds it "
                "after the last key; Insert / Replace act at the selected key"
            )
            return centre

    def preview_at(self, xy) -> int:
        """A click (or hover) on the pad at expression-space point ``xy``: preview the
        nearest centre of the shown level (held to the candidates while picks are)."""
        with self._lock:
            self.last_click = np.asarray(xy, np.float64)
            return self.preview_centre(self.nearest_centre(xy))

    def _edit(self, keys: list[int], what: str) -> bool:
        """Replace the key centres by ``keys`` (bridged where not linked); False and a
        message if no valid route results."""
        try:
            new, notes = self.routes.bridge(self.level, keys)
            if new:
                self.routes.make(self.level, new)
        except NavigationError as e:
            self.message = f"not {what}: {e}"
            return False
        self._push()
        self.picks = new
        self.anchors = None
        self._rebuild()
        self.selected_key = min(self.selected_key, max(len(new) - 1, 0))
        self.message = f"{what}; keys {' → '.join(map(str, new)) or 'none'}" + (
            " (" + "; ".join(notes) + ")" if notes else ""
        )
        return True

    def _target(self, centre: int | None) -> int | None:
        c = self.preview if centre is None else int(centre)
        if c is None:
            self.message = "click a centre on the pad first (to preview it), then choose"
            return None
        if self._restricted() and c not in set(self.candidates().tolist()):
            self.message = (
                f"not used: centre {c} is not near the route of level {self.guide.level}; "  # type: ignore[union-attr]
                "untick 'Restrict to candidates' to choose freely"
            )
            return None
        return c

    def _key_index(self, index: int | None, n: int) -> int | None:
        i = self.selected_key if index is None else int(index)
        if not 0 <= i < n:
            self.message = f"key #{i} does not exist (keys 0 … {n - 1})" if n else "no keys yet"
            return None
        return i

    def commit(self, centre: int | None = None) -> bool:
        """Append the previewed centre (or ``centre``) after the last key."""
        with self._lock:
            c = self._target(centre)
            if c is None:
                return False
            ok = self._edit([*self.picks, c], f"committed centre {c}")
            if ok:
                self.selected_key = len(self.picks) - 1
            return ok

    def insert_key(self, index: int | None = None, centre: int | None = None) -> bool:
        """Insert the previewed centre (or ``centre``) before key ``index`` (default the
        selected key; ``len(picks)`` appends)."""
        with self._lock:
            c = self._target(centre)
            i = self.selected_key if index is None else int(index)
            if c is None:
                return False
            if not 0 <= i <= len(self.picks):
                self.message = f"cannot insert at #{i}: positions are 0 … {len(self.picks)}"
                return False
            return self._edit([*self.picks[:i], c, *self.picks[i:]],
                              f"inserted centre {c} at #{i}")  # fmt: skip

    def replace_key(self, index: int | None = None, centre: int | None = None) -> bool:
        """Replace key ``index`` (default the selected key) by the previewed centre."""
        with self._lock:
            c = self._target(centre)
            i = self._key_index(index, len(self.picks))
            if c is None or i is None:
                return False
            old = self.picks[i]
            return self._edit([*self.picks[:i], c, *self.picks[i + 1 :]],
                              f"replaced key #{i} ({old}) by {c}")  # fmt: skip

    def delete_key(self, index: int | None = None) -> bool:
        """Delete key ``index`` (default the selected key); its neighbours are joined."""
        with self._lock:
            i = self._key_index(index, len(self.picks))
            if i is None:
                return False
            old, before = self.picks[i], list(self.picks)
            ok = self._edit([*self.picks[:i], *self.picks[i + 1 :]],
                            f"deleted key #{i} ({old})")  # fmt: skip
            if ok and self.picks == before:
                self.message += f" — centre {old} is the only link between its neighbours"
            return ok

    def select_key(self, index: int) -> None:
        """Choose the key position that insert / replace / delete act on."""
        with self._lock:
            i = int(index)
            if not 0 <= i <= len(self.picks):
                raise NavigationError(f"key # must lie in [0, {len(self.picks)}], got {i}")
            self.selected_key = i
            if i < len(self.picks):
                lv = self.data.hierarchy.levels[self.level]
                self.selected_frame = int(lv.center_frames[self.picks[i]])

    def level_up(self) -> None:
        """One level coarser (no-op at level 0)."""
        if self.level > 0:
            self.set_level(self.level - 1)

    def level_down(self) -> None:
        """One level finer (no-op at the finest)."""
        if self.level + 1 < self.n_levels:
            self.set_level(self.level + 1)

    def toggle_play(self) -> bool:
        """Play / pause the route (a message when there is none); returns ``playing``."""
        with self._lock:
            self.playing = not self.playing and self.route is not None
            if self.route is None:
                self.message = "pick key centres first"
            return self.playing

    def undo(self) -> None:
        """Go back one action (a pick, a level change, a refinement, a clear)."""
        with self._lock:
            if not self._history:
                self.message = "nothing to undo"
                return
            s = self._history.pop()
            self._restore(s)
            self.message = f"undone (level {self.level})"

    def clear(self) -> None:
        with self._lock:
            self._push()
            self.picks, self.anchors, self.guide = [], None, None
            self._rebuild()
            self.message = "cleared"

    def set_restrict(self, on: bool) -> None:
        self.restrict = bool(on)
        self.message = "picks held to the candidates" if on else "picks free at every level"

    def refine(self) -> None:
        """Automatic refinement of the route to the next level."""
        with self._lock:
            if self.route is None:
                self.message = "pick key centres first"
                return
            if self.route.level + 1 >= self.n_levels:
                self.message = "already at the finest level: the route is the animation"
                return
            self._push()
            r = self.routes.refine(self.route)
            self.guide = self.route
            self.level = r.level
            self.picks = list(r.centres)
            self.anchors = r.anchors
            self._rebuild()
            self.message = f"refined to level {self.level}"

    def candidates(self) -> np.ndarray:
        """Centres of the shown level near the guide route (empty without a guide)."""
        if self.guide is None:
            return np.zeros(0, int)
        return self._candidates(self.level, self.guide.frames)

    def _candidates(self, level: int, frames) -> np.ndarray:
        # asked on every status line: recent answers are kept (a route's frames never
        # change; the frames object is held, so its id is not reused while kept)
        key = (int(level), id(frames))
        hit = self._cand.get(key)
        if hit is None or hit[0] is not frames:
            if len(self._cand) >= 8:
                self._cand.clear()
            hit = self._cand[key] = (frames, self.routes.candidates(level, frames))
        return hit[1]

    def next_candidates(self) -> np.ndarray:
        """Centres of the next level near the shown route."""
        if self.route is None or self.level + 1 >= self.n_levels:
            return np.zeros(0, int)
        return self._candidates(self.level + 1, self.route.frames)

    def status(self) -> dict:
        """What the status panel shows, as data (`NavigatorView` renders it): the shown
        ``level`` of ``n_levels`` with ``n_clusters`` centres and ``bridges`` (links the
        paper's ρ rule does not allow, added to join the level's pieces), ``fcm`` (why the
        level's FCM is not at its fixed point, "" when it is), the ``keys``, the
        ``preview`` centre and ``selected_key`` (or ``None``), the route's ``route_frames``
        and ``route_level``, ``density`` (frames drawn as one image) with ``n_frames`` and
        ``centres_by_density``, ``guide_level`` (the kept route's level or ``None``) with
        its ``candidates`` and whether picks are ``restricted`` to them, the
        ``next_candidates`` one level down, the selected ``frame``, ``playing``, the last
        ``message``, and ``pieces``: the pieces a k-NN graph was in before they were
        joined at their closest frames (0: one piece)."""
        r = self.route
        return {
            "level": self.level,
            "n_levels": self.n_levels,
            "n_clusters": int(self.data.hierarchy.levels[self.level].n_clusters),
            "bridges": _bridge_count(self.data.hierarchy.levels[self.level]),
            "fcm": fcm_status(self.data.hierarchy.levels[self.level]),
            "keys": [int(k) for k in self.picks],
            "preview": None if self.preview is None else int(self.preview),
            "selected_key": int(self.selected_key) if self.picks else None,
            "route_frames": 0 if r is None else len(r.frames),
            "route_level": None if r is None else int(r.level),
            "density": self.pad_mode == "density",
            "n_frames": self.n_frames,
            "centres_by_density": bool(self.centres_by_density),
            "guide_level": None if self.guide is None else int(self.guide.level),
            "candidates": np.asarray(self.candidates()).tolist(),
            "restricted": self._restricted(),
            "next_candidates": np.asarray(self.next_candidates()).tolist(),
            "frame": int(self.selected_frame),
            "pieces": len((self.data.joins or {}).get("pieces", ())),
            "playing": bool(self.playing),
            "message": self.message,
        }
