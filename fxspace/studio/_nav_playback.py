"""Playback and export of the navigator's route (`NavigatorController.playback`, `step`,
`export`), mixed into `NavigatorController`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fxspace.navigation import NavigationError, Route, playback, rigid_align
from fxspace.studio._nav_data import NavData


class _RoutePlayback:
    """The route's playback (output frames at ``fps``, looping when ``loop``) and its
    export (TRC, JSON, GIF/MP4); the state is `NavigatorController`'s."""

    data: NavData
    route: Route | None
    loop: bool
    playing: bool
    play_index: int
    selected_frame: int
    message: str
    _play: Any
    _lock: Any

    def playback(self, fps: float = 30.0):
        if self.route is None:
            return None
        if self._play is None:
            d = self.data
            self._play = playback(
                self.route.frames, d.hierarchy.embedding, d.positions, fps=fps, rate=d.rate,
                duration=max(2.0, len(self.route.frames) / d.rate),
            )  # fmt: skip
        return self._play

    def step(self) -> int | None:
        """Advance playback by one output frame (wrapping when ``loop``, else stopping at
        the end); returns the frame shown."""
        with self._lock:
            pb = self.playback()
            if pb is None:
                return None
            nxt = self.play_index + 1
            if nxt >= len(pb.times):
                if not self.loop:
                    self.playing = False
                    return self.selected_frame
                nxt = 0
            self.play_index = nxt
            self.selected_frame = int(pb.frame[self.play_index])
            return self.selected_frame

    def export(self, out_dir: str | Path, animation: str = "gif") -> list[Path]:
        """Write the route: ``route.trc`` (the markers of the path's frames, rigidly
        aligned, at the capture rate), ``route.json`` and ``route.gif``/``.mp4``."""
        from fxspace.io import MarkerSequence, write_trc
        from fxspace.plot import write_navigation_animation
        from fxspace.runs import write_json_atomic

        with self._lock:
            if self.route is None:
                raise NavigationError("no route to export: pick key centres first")
            route, pb = self.route, self.playback()
        d = self.data
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        names = d.marker_names or tuple(f"M{i}" for i in range(d.positions.shape[1]))
        P = rigid_align(d.positions[route.frames], d.positions[route.frames[0]])
        paths = [write_trc(out / "route.trc", MarkerSequence(P, names, d.rate, "mm"))]
        paths.append(write_json_atomic(out / "route.json", {
            "level": route.level, "centres": list(route.centres),
            "key_frames": route.key_frames, "frames": route.frames,
            "threshold": d.threshold, "threshold_source": d.threshold_source,
        }))  # fmt: skip
        if animation != "none":
            paths.append(
                write_navigation_animation(
                    out / f"route.{animation}",
                    pb,
                    d.hierarchy.embedding,
                    names=d.marker_names or None,
                    max_frames=120,
                    title=f"level {route.level}: {len(route.frames)} frames",
                )  # fmt: skip
            )
        self.message = "exported " + ", ".join(p.name for p in paths)
        return [Path(p) for p in paths]
