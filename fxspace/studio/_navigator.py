"""Interactive navigator in the browser (optional extra: ``pip install -e ".[viewer]"``).

``fxspace view RUN_DIR`` or ``fxspace view configs/navigation.toml`` builds the expression
space and its hierarchy from the run's (or file's) config and serves a viser page with:

- the 2-D expression pad: every frame (grey), the current level's centres (click one to
  pick it as the next key centre), links (thin blue), the route (red) and a moving cross;
- a level slider, the key centres picked so far, the candidate centres near the route,
  buttons to pick by number, undo, clear, refine automatically to the next level, and
  play/pause the route;
- the 3-D face (markers joined by a fixed wireframe) of the selected / playing frame.

The navigation logic lives in :class:`NavigatorController` (plain Python, testable without
a browser); :func:`serve_navigator` wires it to a viser server.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.navigation import navigation_space
from fxspace.navigation._hierarchy import Hierarchy
from fxspace.navigation._playback import playback, rigid_align
from fxspace.navigation._routes import (
    NavigationError,
    Route,
    make_route,
    path_candidates,
    refine_route,
)

__all__ = ["NavData", "NavigatorController", "load_nav_data", "serve_navigator", "serve"]

_MAX_CLICKABLE = 160


@dataclass(frozen=True)
class NavData:
    """What the navigator shows: the hierarchy, the frame graph's geodesics, the markers."""

    hierarchy: Hierarchy
    geodesics: object
    positions: np.ndarray  # (T, M, 3)
    marker_names: tuple[str, ...] = ()
    rate: float = 60.0


def load_nav_data(target: str | Path, *, restarts: int = 0) -> NavData:
    """Build :class:`NavData` from a navigation run folder (its ``config.toml``) or a config
    file (``experiment = "navigation"``)."""

    import jax

    from fxspace.config import ConfigError, config_from_dict, load_toml
    from fxspace.datasets import FaceData, load_face

    p = Path(target)
    cfg_path = p / "config.toml" if p.is_dir() else p
    if not cfg_path.is_file():
        raise FxspaceError(f"{target}: not a run folder with config.toml nor a config file")
    raw = load_toml(cfg_path)
    if raw.get("experiment") != "navigation":
        raise FxspaceError(
            f"{cfg_path}: experiment must be 'navigation' to view, got {raw.get('experiment')!r}"
        )
    seed = int(raw.get("seed", 0))
    data = config_from_dict(FaceData, raw.get("data", {}))
    graph = dict(raw.get("graph", {}))
    hier = {k: v for k, v in raw.get("hierarchy", {}).items() if k != "compare_cold"}
    hier["max_link_centres"] = hier.get("max_link_centres") or None
    hier["restarts"] = restarts
    face = load_face(data, seed)
    try:
        ns = navigation_space(
            face.positions,
            graph.get("threshold") or None,
            threshold_factor=graph.get("threshold_factor", 1.25),
            dtype=graph.get("dtype", "float32"),
            key=jax.random.PRNGKey(seed),
            hierarchy=hier,
        )
    except TypeError as e:
        raise ConfigError(f"{cfg_path}: [hierarchy] {e}") from e
    geo = ns.space.geodesics
    return NavData(
        ns.hierarchy, geo, np.asarray(face.positions), tuple(face.marker_names), face.rate
    )


class NavigatorController:
    """The navigator's state and actions, independent of any UI.

    ``level`` is the level shown; ``picks`` the key centres picked there; ``route`` the route
    through them (None until a pick); ``message`` the last status or error line.
    """

    def __init__(self, data: NavData):
        self.data = data
        self.level = 0
        self.picks: list[int] = []
        self.route: Route | None = None
        self.anchors: tuple[int, ...] | None = None
        self.message = "click a centre (or type its number) to pick the first key centre"
        self.selected_frame = int(data.hierarchy.levels[0].center_frames[0])
        self.play_index = 0
        self.playing = False
        self._play = None
        self._lock = threading.RLock()

    @property
    def n_levels(self) -> int:
        return len(self.data.hierarchy.levels)

    def _rebuild(self) -> None:
        self._play = None
        self.play_index = 0
        if not self.picks:
            self.route = None
            return
        self.route = make_route(
            self.data.hierarchy, self.data.geodesics, self.level, self.picks, anchors=self.anchors
        )

    def set_level(self, level: int) -> None:
        with self._lock:
            level = int(level)
            if not 0 <= level < self.n_levels:
                raise NavigationError(f"level must be in [0, {self.n_levels - 1}]")
            if level != self.level:
                self.level = level
                self.picks = []
                self.anchors = None
                self._rebuild()
                self.message = f"level {level}: pick key centres"

    def pick(self, centre: int) -> bool:
        """Append ``centre`` to the key centres; False (and a message) if not allowed."""
        with self._lock:
            lv = self.data.hierarchy.levels[self.level]
            centre = int(centre)
            try:
                make_route(
                    self.data.hierarchy, self.data.geodesics, self.level, [*self.picks[-1:], centre]
                )
            except NavigationError as e:
                self.message = f"not picked: {e}"
                return False
            self.picks.append(centre)
            self.selected_frame = int(lv.center_frames[centre])
            self._rebuild()
            self.message = f"picked centre {centre} (frame {self.selected_frame})"
            return True

    def undo(self) -> None:
        with self._lock:
            if self.picks:
                self.picks.pop()
            self._rebuild()
            self.message = "undone"

    def clear(self) -> None:
        with self._lock:
            self.picks = []
            self.anchors = None
            self._rebuild()
            self.message = "cleared"

    def refine(self) -> None:
        """Automatic refinement of the route to the next level."""
        with self._lock:
            if self.route is None:
                self.message = "pick key centres first"
                return
            if self.level + 1 >= self.n_levels:
                self.message = "already at the finest level: the route is the animation"
                return
            r = refine_route(self.data.hierarchy, self.data.geodesics, self.route)
            self.level = r.level
            self.picks = list(r.centres)
            self.anchors = r.anchors
            self._rebuild()
            self.message = f"refined to level {self.level}"

    def candidates(self) -> np.ndarray:
        """Centres of the next level near the current route."""
        if self.route is None or self.level + 1 >= self.n_levels:
            return np.zeros(0, int)
        return path_candidates(self.data.hierarchy, self.level + 1, self.route.frames)

    def playback(self, fps: float = 30.0):
        if self.route is None:
            return None
        if self._play is None:
            d = self.data
            self._play = playback(
                self.route.frames,
                d.hierarchy.embedding,
                d.positions,
                fps=fps,
                rate=d.rate,
                duration=max(2.0, len(self.route.frames) / d.rate),
            )
        return self._play

    def step(self) -> int | None:
        """Advance playback by one output frame; returns the frame shown."""
        with self._lock:
            pb = self.playback()
            if pb is None:
                return None
            self.play_index = (self.play_index + 1) % len(pb.times)
            self.selected_frame = int(pb.frame[self.play_index])
            return self.selected_frame

    def status(self) -> str:
        lv = self.data.hierarchy.levels[self.level]
        keys = " → ".join(map(str, self.picks)) if self.picks else "none"
        n = len(self.route.frames) if self.route is not None else 0
        cand = self.candidates()
        cand_s = ", ".join(map(str, cand[:30])) + (" …" if len(cand) > 30 else "")
        return (
            f"**Level {self.level}** of {self.n_levels - 1}: {lv.n_clusters} centres  \n"
            f"Key centres: {keys}  \n"
            f"Route: {n} frames  \n"
            f"Candidates at level {self.level + 1}: {cand_s or '—'}  \n"
            f"Frame: {self.selected_frame}  \n"
            f"{'Playing' if self.playing else 'Paused'}  \n"
            f"_{self.message}_"
        )


def _pad_coords(xy: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    centre = (xy.max(0) + xy.min(0)) / 2
    scale = 2.0 / max(float(np.ptp(xy, axis=0).max()), 1e-12)
    return centre, scale, np.c_[(xy - centre) * scale, np.zeros(len(xy))]


def serve_navigator(
    data: NavData,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = True,
    block: bool = True,
    fps: float = 30.0,
):
    """Serve the navigator for ``data``; ``port=0`` picks a free port (read it with
    ``server.get_port()``). With ``block=False`` returns ``(server, controller)`` at once
    (stop with ``server.stop()``)."""
    try:
        import viser
    except ImportError as e:
        raise FxspaceError(
            f"the navigator needs the optional viewer extra: pip install -e '.[viewer]' ({e})"
        ) from e

    from fxspace.plot._navigation import face_frame, face_wireframe

    ctl = NavigatorController(data)
    h = data.hierarchy
    xy = np.asarray(h.embedding)
    _, scale, pad = _pad_coords(xy)
    server = viser.ViserServer(host=host, port=port, verbose=False)
    if not environment_map:
        server.scene.configure_environment_map(None)
    server.scene.set_up_direction("+y")
    # everything lies in the x–y plane, seen from +z: the pad left, the face right
    server.initial_camera.position = (1.3, 0.0, 4.5)
    server.initial_camera.look_at = (1.3, 0.0, 0.0)
    server.initial_camera.up = (0.0, 1.0, 0.0)
    server.scene.add_point_cloud(
        "/pad/frames", pad.astype(np.float32), colors=(190, 190, 190), point_size=0.012
    )

    # the face: markers aligned to the first frame, seen from the front, right of the pad
    P = rigid_align(data.positions, data.positions[0])
    R = face_frame(P[0], data.marker_names or None)
    fc = P[0].mean(0)
    F = (P - fc) @ R.T  # right, up, out
    fscale = 1.6 / max(float(np.ptp(F[..., :2])), 1e-12)
    Fw = F * fscale + np.array([2.6, 0.0, 0.0])
    edges = face_wireframe(P[0], data.marker_names or None)

    handles: dict = {"centres": []}
    gui_status = server.gui.add_markdown(ctl.status())
    level_slider = server.gui.add_slider(
        "Level",
        min=0,
        max=max(ctl.n_levels - 1, 1),
        step=1,
        initial_value=0,
        disabled=ctl.n_levels < 2,
    )
    pick_text = server.gui.add_text("Centre", initial_value="0")
    pick_btn = server.gui.add_button("Pick centre")
    undo_btn = server.gui.add_button("Undo")
    clear_btn = server.gui.add_button("Clear")
    refine_btn = server.gui.add_button("Refine")
    play_btn = server.gui.add_button("Play / Pause")

    def draw_face(frame: int) -> None:
        pts = Fw[frame].astype(np.float32)
        server.scene.add_point_cloud("/face/markers", pts, colors=(220, 60, 60), point_size=0.03)
        if len(edges):
            server.scene.add_line_segments(
                "/face/wire", pts[edges], colors=(70, 70, 70), thickness=0.004
            )

    def draw_cross(frame_xy: np.ndarray) -> None:
        q = np.r_[frame_xy, 0.0]
        d = 0.06
        seg = np.array([[q - [d, 0, 0], q + [d, 0, 0]], [q - [0, d, 0], q + [0, d, 0]]])
        server.scene.add_line_segments(
            "/pad/cross", seg.astype(np.float32), colors=(0, 0, 0), thickness=0.01
        )

    def draw_level() -> None:
        lv = h.levels[ctl.level]
        for hd in handles["centres"]:
            hd.remove()
        handles["centres"] = []
        cp = pad[lv.center_frames]
        if lv.links is not None and lv.n_clusters <= 400:
            i, j = np.nonzero(np.triu(lv.links, 1))
            if len(i):
                server.scene.add_line_segments(
                    "/pad/links",
                    np.stack([cp[i], cp[j]], 1).astype(np.float32),
                    colors=(80, 120, 220),
                    thickness=0.003,
                )
            else:
                server.scene.remove_by_name("/pad/links")
        else:
            server.scene.remove_by_name("/pad/links")
        if lv.n_clusters <= _MAX_CLICKABLE:
            server.scene.remove_by_name("/pad/centres_cloud")
            r = 0.035 if lv.n_clusters <= 40 else 0.02
            for k in range(lv.n_clusters):
                hd = server.scene.add_icosphere(
                    f"/pad/centre_{k}", radius=r, color=(40, 100, 200), position=tuple(cp[k])
                )
                hd.on_click(lambda _e, k=k: on_pick(k))
                handles["centres"].append(hd)
        else:
            server.scene.add_point_cloud(
                "/pad/centres_cloud", cp.astype(np.float32), colors=(40, 100, 200), point_size=0.02
            )

    def draw_route() -> None:
        server.scene.remove_by_name("/pad/route")
        server.scene.remove_by_name("/pad/keys")
        if ctl.route is not None and len(ctl.route.frames) > 1:
            p = pad[ctl.route.frames]
            server.scene.add_line_segments(
                "/pad/route",
                np.stack([p[:-1], p[1:]], 1).astype(np.float32),
                colors=(220, 40, 40),
                thickness=0.008,
            )
        if ctl.route is not None:
            server.scene.add_point_cloud(
                "/pad/keys",
                pad[ctl.route.key_frames].astype(np.float32),
                colors=(220, 40, 40),
                point_size=0.05,
            )

    def refresh(full: bool = False) -> None:
        if full:
            draw_level()
        draw_route()
        draw_face(ctl.selected_frame)
        draw_cross(pad[ctl.selected_frame, :2])
        gui_status.content = ctl.status()

    def on_pick(k: int) -> None:
        ctl.pick(k)
        refresh()

    @level_slider.on_update
    def _(_e) -> None:
        if int(level_slider.value) != ctl.level:
            ctl.set_level(int(level_slider.value))
            refresh(full=True)

    @pick_btn.on_click
    def _(_e) -> None:
        try:
            k = int(str(pick_text.value).strip())
        except ValueError:
            ctl.message = f"not a centre number: {pick_text.value!r}"
            refresh()
            return
        if not 0 <= k < h.levels[ctl.level].n_clusters:
            ctl.message = f"centre {k} does not exist at level {ctl.level}"
            refresh()
            return
        on_pick(k)

    @undo_btn.on_click
    def _(_e) -> None:
        ctl.undo()
        refresh()

    @clear_btn.on_click
    def _(_e) -> None:
        ctl.clear()
        refresh()

    @refine_btn.on_click
    def _(_e) -> None:
        before = ctl.level
        ctl.refine()
        if ctl.level != before:
            level_slider.value = ctl.level
            refresh(full=True)
        else:
            refresh()

    @play_btn.on_click
    def _(_e) -> None:
        ctl.playing = not ctl.playing and ctl.route is not None
        if ctl.route is None:
            ctl.message = "pick key centres first"
        refresh()

    stop = threading.Event()

    def player() -> None:
        while not stop.is_set():
            if ctl.playing:
                try:
                    ctl.step()
                    pb = ctl.playback()
                    if pb is not None and not stop.is_set():
                        draw_face(ctl.selected_frame)
                        draw_cross((pb.xy[ctl.play_index] - (xy.max(0) + xy.min(0)) / 2) * scale)
                        gui_status.content = ctl.status()
                except Exception:  # the server is going down
                    if stop.is_set():
                        return
                    raise
            stop.wait(1.0 / fps)

    refresh(full=True)
    thread = threading.Thread(target=player, daemon=True)
    thread.start()
    orig_stop = server.stop

    def stop_all() -> None:
        stop.set()
        thread.join(timeout=5.0)
        orig_stop()

    server.stop = stop_all  # type: ignore[method-assign]
    if not block:
        return server, ctl
    print(f"fxspace navigator on http://{host}:{server.get_port()} (Ctrl-C to stop)")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace view TARGET``: build the navigator from a run folder or config and serve it."""
    print(f"fxspace view: building the expression space and hierarchy of {target} …")
    return serve_navigator(load_nav_data(target), port=port, **kwargs)
