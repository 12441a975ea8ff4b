"""Interactive navigator in the browser (Kim & Jung §4; ``pip install -e ".[viewer]"``).

``fxspace studio configs/navigation.toml`` runs the navigation config first (the threshold
sweep over its frames, the space and the hierarchy are cached stages, built with progress
the first time and read afterwards) and serves a viser page with:

- the 2-D expression pad: every frame (grey points; past ``density_above`` frames, their
  density as one grey image), the shown level's centres (blue) and links (thin blue;
  bridges, which the paper's ρ rule does not allow, orange), the
  route (red), the route kept from another level (orange) with its candidate centres
  (green), the previewed centre (yellow) and a moving cross;
- *look, then choose*: a click anywhere on the pad previews the nearest centre of the
  shown level — its face is shown, nothing is committed (viser reports clicks, not
  hovering, on the scene); **Commit** (or Enter, or a shift-click) appends it to the key
  centres; **Insert before key** / **Replace key** / **Delete key** edit the key at
  "Key #" in place, at any level; the route is recomputed and kept valid (unlinked
  neighbours are bridged along the shortest chain of links, with a note);
- a level slider and Level up / down, "Restrict to candidates", undo (across levels),
  clear, refine, play/pause, loop, and export of the route (GIF/MP4 + TRC);
- keyboard shortcuts (`HOTKEYS`, viser command hotkeys; also in the command palette):
  space play/pause, U undo, ↑/↓ level up/down, Enter commit, I insert, R replace,
  Delete delete;
- the face of the previewed / selected / playing frame: a real head (the ICT Face
  Model's blend shapes, `fxspace.face`) with eyes and teeth, its expression weights and
  head motion solved from that frame's markers, beside the markers; without the rig (or
  markers named to bind to it) the template head (`fxspace.head_model`) driven by the
  markers.

The state lives in `NavigatorController` (``_nav_controller``, testable without a
browser); `NavigatorView` draws it and `serve_navigator` wires the page to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.navigation import link_pairs
from fxspace.studio._nav_controller import (
    DENSITY_ABOVE,
    NavData,
    NavigatorController,
    _short,
    load_nav_data,
)
from fxspace.studio._nav_data import Aligned
from fxspace.studio._server import (
    PadFrame,
    Player,
    ServeOptions,
    attach_stop,
    density_rgba,
    new_server,
    ray_plane_z0,
    run_until_interrupted,
    serialized,
    status_markdown,
    studio_face,
)

__all__ = [
    "DENSITY_ABOVE",
    "NavData",
    "NavigatorController",
    "load_nav_data",
    "serve_navigator",
    "serve",
    "NavigatorView",
    "HOTKEYS",
    "status_text",
]


def status_text(st: dict) -> str:
    """The status panel's Markdown from `NavigatorController.status` (data in, text out)."""
    keys = st["keys"]
    shown = " → ".join(map(str, keys)) if keys else "none"
    if len(keys) > 16:  # a refined route at a fine level: its ends and the count
        shown = (" → ".join(map(str, keys[:6])) + f" → … ({len(keys) - 12} more) → "
                 + " → ".join(map(str, keys[-6:])))  # fmt: skip
    g, rl = st["guide_level"], st["route_level"]
    return status_markdown(
        f"Level {st['level']}",
        [
            f"Frames: {st['n_frames']}, shown by density"
            f"{' (centres too)' if st['centres_by_density'] else ''}"
            if st["density"]
            else "",
            f"Bridges: {st['bridges']} (orange; not links by the paper's ρ rule)"
            if st["bridges"]
            else "",
            f"FCM: {st['fcm']}" if st.get("fcm") else "",
            f"Takes: the graph's {st['pieces']} pieces joined at their closest frames "
            "(metrics: graph_joins)"
            if st.get("pieces")
            else "",
            f"Key centres: {shown}",
            f"Preview: centre {st['preview']}" if st["preview"] is not None else "",
            f"Selected key: #{st['selected_key']}" if st["selected_key"] is not None else "",
            f"Route: {st['route_frames']} frames" + (f" (level {rl})" if rl is not None else ""),
            f"Candidates here (near the level-{g} route): {_short(st['candidates']) or '—'}"
            f"{' — picks held to them' if st['restricted'] else ''}"
            if g is not None
            else "",
            f"Candidates at level {st['level'] + 1}: {_short(st['next_candidates']) or '—'}",
            f"Frame: {st['frame']}",
            "Playing" if st["playing"] else "Paused",
        ],
        st["message"],
        after_title=f" of {st['n_levels'] - 1}: {st['n_clusters']} centres",
    )


LINK_RGB, BRIDGE_RGB = (80, 120, 220), (240, 140, 20)
"""The pad's colours of a link (the paper's ρ rule) and of a bridge (added to join a
level's pieces, `fxspace.navigation.LinkRule(bridges=True)`)."""


def _link_colours(lv, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``(n, 2, 3)`` uint8 colours of the links ``(i, j)``: bridges orange, links blue."""
    out = np.empty((len(i), 2, 3), np.uint8)
    out[:] = LINK_RGB
    br = getattr(lv, "bridges", None)
    if br is not None:
        b = np.asarray(br[i, j]).reshape(-1).astype(bool)
        out[b] = BRIDGE_RGB
    return out


def _segments(p: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    return np.stack([p[i], p[j]], 1).astype(np.float32)


def _draw_frames(server, ctl: NavigatorController, pf: PadFrame, pad: np.ndarray) -> None:
    """Every frame on the pad, below everything else: grey points, or (``pad_mode ==
    "density"``) one image of their 2-D histogram."""
    if ctl.pad_mode == "points":
        server.scene.add_point_cloud(
            "/pad/frames", pad.astype(np.float32), colors=(150, 150, 150), point_size=0.018
        )
        return
    d = ctl.frame_density()
    lo, hi = pf.to_pad(d.lo), pf.to_pad(d.hi)
    # viser's image plane is turned half a turn about x: image row 0 lies at the bottom
    server.scene.add_image(
        "/pad/density", density_rgba(d.counts, (110, 110, 110)),
        render_width=float(hi[0] - lo[0]), render_height=float(hi[1] - lo[1]),
        format="png", position=(*((lo[:2] + hi[:2]) / 2), -0.01),
        cast_shadow=False, receive_shadow=False,
    )  # fmt: skip


_HEAD, _FACE_VERTICES = "face/ict", 6000  # the navigator's head (its warm-up makes the same)


class NavigatorView:
    """The navigator's page: the pad, the face and the controls, drawn from a
    `NavigatorController` (``server.fxspace_view``)."""

    def __init__(self, server, ctl: NavigatorController, face_vertices: int = _FACE_VERTICES,
                 head: str | Path | None = _HEAD):  # fmt: skip
        self.server, self.ctl = server, ctl
        data = ctl.data
        h = data.hierarchy
        self.pf = PadFrame(h.embedding)
        self.pad = self.pf.to_pad(h.embedding)
        # everything lies in the x–y plane, seen from +z: the pad left, the face right
        server.initial_camera.position = (1.4, 0.0, 3.6)
        server.initial_camera.look_at = (1.4, 0.0, 0.0)
        server.initial_camera.up = (0.0, 1.0, 0.0)
        _draw_frames(server, ctl, self.pf, self.pad)
        # the face: markers aligned to the first frame, seen from the front, right of the pad
        # each frame aligned to the first when it is shown (not all 10⁶ frames up front)
        self.P = Aligned(data.positions)
        self.face, self.face_note = studio_face(
            self.P[0], data.marker_names or None, head, face_vertices
        )
        self.R = self.face.axes
        rest = (self.face.rest - self.P[0].mean(0)) @ self.R.T  # right, up, out
        self.fc = self.P[0].mean(0) + ((rest.max(0) + rest.min(0)) / 2) @ self.R
        self.F = self.P.in_face(self.fc, self.R)
        self.fscale = 1.7 / max(float(np.ptp(rest[:, 1])), 1e-12)  # the head ~1.7 tall
        self.gui_status = server.gui.add_markdown(status_text(ctl.status()))
        self.gui_face = server.gui.add_markdown(f"_Face: {self.face_note}_")
        self.gui_dots = server.gui.add_checkbox("Markers on the face", initial_value=False)
        self.gui_dots.on_update(lambda _e: self.draw_face(self.ctl.selected_frame))

    def draw_face(self, frame: int) -> None:
        at = np.array([2.6, 0.1, 0.0])
        V = (self.face.vertices(self.P[frame]) - self.fc) @ self.R.T * self.fscale
        V = (V + at).astype(np.float32)
        for name, v, f, colour in self.face.meshes(V):
            self.server.scene.add_mesh_simple(
                "/face/surface" if name == "skin" else f"/face/{name}", v, f, color=colour,
                side="double", flat_shading=False, cast_shadow=False, receive_shadow=False,
            )  # fmt: skip
        self.server.scene.add_point_cloud(
            "/face/markers", (self.F[frame] * self.fscale * 0.4 + [2.6, -1.45, 0.0]).astype(
                np.float32), colors=(220, 60, 60), point_size=0.025,
        )  # fmt: skip
        if self.gui_dots.value:  # the markers as dots on the face, just in front of it
            self.server.scene.add_point_cloud(
                "/face/dots", (self.F[frame] * self.fscale + at + [0, 0, 0.02]).astype(
                    np.float32), colors=(220, 60, 60), point_size=0.02,
            )  # fmt: skip
        else:
            self.server.scene.remove_by_name("/face/dots")

    def draw_cross(self, q2: np.ndarray) -> None:
        q = np.r_[q2[:2], 0.0]
        d = 0.06
        seg = np.array([[q - [d, 0, 0], q + [d, 0, 0]], [q - [0, d, 0], q + [0, d, 0]]])
        self.server.scene.add_line_segments(
            "/pad/cross", seg.astype(np.float32), colors=(0, 0, 0), thickness=0.01
        )

    def draw_level(self) -> None:
        ctl, scene = self.ctl, self.server.scene
        lv = ctl.data.hierarchy.levels[ctl.level]
        cp = self.pad[lv.center_frames]
        scene.remove_by_name("/pad/links")
        if ctl.centres_by_density:  # the density image shows them; clicks still pick
            scene.remove_by_name("/pad/centres")
            return
        if lv.links is not None:
            i, j = link_pairs(lv.links)
            if len(i):
                scene.add_line_segments(
                    "/pad/links", _segments(cp, i, j), colors=_link_colours(lv, i, j),
                    thickness=0.003 if lv.n_clusters <= 400 else 0.0015,
                )  # fmt: skip
        size = 0.035 if lv.n_clusters <= 40 else (0.025 if lv.n_clusters <= 400 else 0.014)
        scene.add_point_cloud(
            "/pad/centres", cp.astype(np.float32), colors=(40, 100, 200), point_size=size
        )

    def _polyline(self, name: str, frames, color, thickness: float) -> None:
        if frames is not None and len(frames) > 1:
            p = self.pad[np.asarray(frames)]
            self.server.scene.add_line_segments(
                name, np.stack([p[:-1], p[1:]], 1).astype(np.float32), colors=color,
                thickness=thickness,
            )  # fmt: skip

    def _points(self, name: str, frames, color, size: float, z: float) -> None:
        p = self.pad[np.asarray(frames, np.int64)] + [0, 0, z]
        self.server.scene.add_point_cloud(name, p.astype(np.float32), colors=color,
                                          point_size=size)  # fmt: skip

    def draw_route(self) -> None:
        ctl = self.ctl
        for name in ("/pad/route", "/pad/keys", "/pad/guide", "/pad/candidates", "/pad/preview"):
            self.server.scene.remove_by_name(name)
        g, r = ctl.guide, ctl.route
        if g is not None and g is not r:
            self._polyline("/pad/guide", g.frames, (240, 150, 40), 0.006)
        cf = ctl.data.hierarchy.levels[ctl.level].center_frames
        cand = ctl.candidates()
        if len(cand):
            self._points("/pad/candidates", cf[cand], (40, 180, 80), 0.03, 0.01)
        if r is not None:
            self._polyline("/pad/route", r.frames, (220, 40, 40), 0.008)
            self._points("/pad/keys", r.key_frames, (220, 40, 40), 0.04, 0.02)
        if ctl.preview is not None:
            self._points("/pad/preview", [cf[ctl.preview]], (250, 200, 0), 0.06, 0.03)

    def refresh(self, full: bool = False) -> None:
        with _lock(self.server):
            if full:
                self.draw_level()
            self.draw_route()
            self.draw_face(self.ctl.selected_frame)
            self.draw_cross(self.pad[self.ctl.selected_frame])
            self.gui_status.content = status_text(self.ctl.status())
            for hook in getattr(self, "after_refresh", ()):
                hook()


def _lock(server):
    return server._fxspace_draw_lock


def _wire_controls(server, ctl: NavigatorController, view: NavigatorView, export_dir) -> None:
    """The GUI controls, each wired to one controller method, then a redraw."""
    gui = server.gui
    level_slider = gui.add_slider(
        "Level", min=0, max=max(ctl.n_levels - 1, 1), step=1, initial_value=0,
        disabled=ctl.n_levels < 2,
    )  # fmt: skip
    restrict_box = gui.add_checkbox("Restrict to candidates", initial_value=ctl.restrict)
    pick_text = gui.add_text("Centre", initial_value="0")
    key_num = gui.add_number("Key #", initial_value=0, min=0, step=1)
    buttons = {
        name: gui.add_button(name)
        for name in ("Preview centre", "Commit", "Insert before key", "Replace key",
                     "Delete key", "Pick centre", "Level up (coarser)",
                     "Level down (finer)", "Undo", "Clear", "Refine", "Play / Pause")
    }  # fmt: skip
    loop_box = gui.add_checkbox("Loop", initial_value=ctl.loop)
    fmt = gui.add_dropdown("Export as", ("gif", "mp4", "none"), initial_value="gif")
    export_btn = gui.add_button("Export route")

    def sync() -> None:
        if int(level_slider.value) != ctl.level:
            level_slider.value = ctl.level

    view.after_refresh = (sync,)

    def centre_number() -> int | None:
        try:
            return int(str(pick_text.value).strip())
        except ValueError:
            ctl.message = f"not a centre number: {pick_text.value!r}"
            return None

    def keyed(fn):  # act at the key # of the box
        def act():
            ctl.select_key(min(max(int(key_num.value), 0), len(ctl.picks)))
            fn()

        return act

    def preview() -> None:
        k = centre_number()
        if k is not None:
            try:
                ctl.preview_centre(k)
            except Exception as e:  # shown to the user
                ctl.message = str(e)

    def pick() -> None:
        k = centre_number()
        if k is not None:
            ctl.pick(k)

    def export() -> None:
        try:
            ctl.export(export_dir, str(fmt.value))
        except Exception as e:  # shown to the user, not raised into the server thread
            ctl.message = f"export failed: {e}"

    actions = {
        "Preview centre": preview, "Commit": ctl.commit, "Pick centre": pick,
        "Insert before key": keyed(ctl.insert_key), "Replace key": keyed(ctl.replace_key),
        "Delete key": keyed(ctl.delete_key), "Level up (coarser)": ctl.level_up,
        "Level down (finer)": ctl.level_down, "Undo": ctl.undo, "Clear": ctl.clear,
        "Refine": ctl.refine, "Play / Pause": ctl.toggle_play,
    }  # fmt: skip
    for name, fn in actions.items():
        buttons[name].on_click(_run_then_refresh(view, fn))
    export_btn.on_click(_run_then_refresh(view, export))
    level_slider.on_update(_run_then_refresh(view, lambda: ctl.set_level(int(level_slider.value))))
    restrict_box.on_update(_run_then_refresh(view, lambda: ctl.set_restrict(restrict_box.value)))
    loop_box.on_update(lambda _e: setattr(ctl, "loop", bool(loop_box.value)))
    _wire_keys(server, ctl, view)


def _run_then_refresh(view: NavigatorView, fn):
    def handler(_event=None) -> None:
        before = view.ctl.level
        fn()
        view.refresh(full=view.ctl.level != before)

    return handler


#: keyboard shortcuts (viser command-palette hotkeys): key → (label, controller method)
HOTKEYS = {
    "space": ("Play / pause", "toggle_play"),
    "U": ("Undo", "undo"),
    "enter": ("Commit the previewed centre", "commit"),
    "I": ("Insert the previewed centre before the selected key", "insert_key"),
    "R": ("Replace the selected key by the previewed centre", "replace_key"),
    "delete": ("Delete the selected key", "delete_key"),
    "arrowup": ("Level up (coarser)", "level_up"),
    "arrowdown": ("Level down (finer)", "level_down"),
}


def _wire_keys(server, ctl: NavigatorController, view: NavigatorView) -> None:
    """`HOTKEYS` as viser commands (each also in the command palette)."""
    for key, (label, method) in HOTKEYS.items():
        cmd = server.gui.add_command(label, hotkey=key)
        cmd.on_trigger(_run_then_refresh(view, getattr(ctl, method)))


def serve_navigator(
    data: NavData,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = False,
    block: bool = True,
    fps: float = 30.0,
    export_dir: str | Path = "navigator_export",
    face_vertices: int = _FACE_VERTICES,
    density_above: int = DENSITY_ABOVE,
    options: ServeOptions | None = None,
    head: str | Path | None = _HEAD,
):
    """Serve the navigator for ``data``; ``port=0`` picks a free port (read it with
    ``server.get_port()``; or pass `options`, a `ServeOptions`, which wins over the
    keywords). With ``block=False`` returns ``(server, controller)`` at once (stop with
    ``server.stop()``; the page's `NavigatorView` is ``server.fxspace_view``). Exports go
    to ``export_dir``. Past ``density_above`` frames the pad shows their density (one
    image) instead of one point per frame. The face is the rig at ``head`` (a path, or
    one under the data root; the ICT Face Model by default) solved from each frame's
    markers when the markers bind to it, else the template head (``head=None``).

    A click on the pad previews the nearest centre (its face, nothing committed); a
    shift-click commits it at once. Keyboard shortcuts: `HOTKEYS`."""
    o = options or ServeOptions(port, host, fps, block, environment_map)
    server = new_server(o.port, o.host, o.environment_map)
    serialized(server)  # creates the drawing lock
    ctl = NavigatorController(data, density_above=density_above)
    view = NavigatorView(server, ctl, face_vertices, head)
    server.fxspace_view = view
    _wire_controls(server, ctl, view, export_dir)

    def on_pad(commit: bool):
        def handler(event) -> None:
            hit = ray_plane_z0(event.ray_origin, event.ray_direction)
            if hit is None or hit[0] > 1.3:  # the face side of the scene
                return
            ctl.preview_at(view.pf.to_space(hit[:2]))
            if commit:
                ctl.commit()
            view.refresh()

        return handler

    server.scene.on_click()(on_pad(False))
    server.scene.on_click(modifier="shift")(on_pad(True))

    @serialized(server)
    def tick() -> None:
        ctl.step()
        pb = ctl.playback()
        if pb is not None:
            view.draw_face(ctl.selected_frame)
            view.draw_cross(view.pf.to_pad(pb.xy[ctl.play_index]))
            view.gui_status.content = status_text(ctl.status())

    view.refresh(full=True)
    attach_stop(server, Player(tick, lambda: ctl.playing, o.fps))
    if o.block:
        run_until_interrupted(server, "navigator", o.host)
    return server, ctl


def warm(config: str | Path, **kwargs) -> None:
    """What the navigator of ``config`` needs besides the run's stages, made ahead
    (`fxspace.studio.serve_config` runs it in a thread while the stages are prepared):
    the face solved from the first frame's markers — the rig read and bound, its solver
    compiled (`studio_face` keeps it for the app) — and one frame posed."""
    from fxspace.datasets import load_face
    from fxspace.pipelines import resolve_config

    spec = resolve_config(config, experiment=("navigation", "navigation_scale"))[0]
    face = load_face(spec.config.data, spec.seed)
    P = Aligned(face.positions)
    f, _ = studio_face(P[0], tuple(face.marker_names) or None, kwargs.get("head", _HEAD),
                       kwargs.get("face_vertices", _FACE_VERTICES))  # fmt: skip
    f.vertices(P[min(1, len(face.positions) - 1)])


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a navigation run folder (its cached stages are read)
    or config (computed without a cache): load and serve."""
    print(f"fxspace studio: loading the expression space and hierarchy of {target} …")
    p = Path(target)
    kwargs.setdefault("export_dir", (p if p.is_dir() else Path(".")) / "navigator_export")
    return serve_navigator(load_nav_data(target), port=port, **kwargs)
