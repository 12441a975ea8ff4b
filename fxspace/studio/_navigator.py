"""Interactive navigator in the browser (Kim & Jung §3.5–3.6; ``pip install -e ".[viewer]"``).

``fxspace studio RUN_DIR`` (or a navigation config) builds the expression space and its
hierarchy and serves a viser page with:

- the 2-D expression pad: every frame (grey points; past ``density_above`` frames, their
  density as one grey image), the shown level's centres (blue) and links
  (thin blue) at every level, the route (red), the route kept from another level (orange)
  with its candidate centres (green), and a moving cross; a click anywhere on the pad
  picks the nearest centre of the shown level (a grid index, not a widget per centre);
- a level slider (jump to any level), "Restrict to candidates", the key centres, buttons
  to pick by number, undo (across levels), clear, refine, play/pause, loop, and export of
  the route (GIF/MP4 + TRC of the path's frames);
- the face of the selected / playing frame: a shaded dense surface driven by the markers
  through the RBF transfer, beside the markers.

The state lives in :class:`NavigatorController` (``_nav_controller``, testable without a
browser); :func:`serve_navigator` draws it and wires the page to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.navigation._playback import rigid_align
from fxspace.studio._nav_controller import (
    DENSITY_ABOVE,
    NavData,
    NavigatorController,
    load_nav_data,
)
from fxspace.studio._server import (
    DenseFace,
    PadFrame,
    Player,
    attach_stop,
    density_rgba,
    new_server,
    ray_plane_z0,
    run_until_interrupted,
    serialized,
)

__all__ = [
    "DENSITY_ABOVE",
    "NavData",
    "NavigatorController",
    "load_nav_data",
    "serve_navigator",
    "serve",
]


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


def serve_navigator(
    data: NavData,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = True,
    block: bool = True,
    fps: float = 30.0,
    export_dir: str | Path = "navigator_export",
    face_vertices: int = 2500,
    density_above: int = DENSITY_ABOVE,
):
    """Serve the navigator for ``data``; ``port=0`` picks a free port (read it with
    ``server.get_port()``). With ``block=False`` returns ``(server, controller)`` at once
    (stop with ``server.stop()``). Exports go to ``export_dir``. Past ``density_above``
    frames the pad shows their density (one image) instead of one point per frame."""
    from fxspace.plot._navigation import face_frame

    server = new_server(port, host, environment_map)
    ctl = NavigatorController(data, density_above=density_above)
    h = data.hierarchy
    pf = PadFrame(h.embedding)
    pad = pf.to_pad(h.embedding)
    # everything lies in the x–y plane, seen from +z: the pad left, the face right
    server.initial_camera.position = (1.4, 0.0, 3.6)
    server.initial_camera.look_at = (1.4, 0.0, 0.0)
    server.initial_camera.up = (0.0, 1.0, 0.0)
    _draw_frames(server, ctl, pf, pad)

    # the face: markers aligned to the first frame, seen from the front, right of the pad
    P = rigid_align(data.positions, data.positions[0])
    R = face_frame(P[0], data.marker_names or None)
    fc = P[0].mean(0)
    F = (P - fc) @ R.T  # right, up, out
    fscale = 1.6 / max(float(np.ptp(F[..., :2])), 1e-12)
    offset = np.array([2.6, 0.0, 0.0])
    face = DenseFace(P[0], face_vertices)
    marker_scale = 0.45  # the markers, smaller, below-right of the surface
    moff = np.array([3.45, -0.7, 0.0])

    gui_status = server.gui.add_markdown(ctl.status())
    level_slider = server.gui.add_slider(
        "Level", min=0, max=max(ctl.n_levels - 1, 1), step=1, initial_value=0,
        disabled=ctl.n_levels < 2,
    )  # fmt: skip
    restrict_box = server.gui.add_checkbox("Restrict to candidates", initial_value=ctl.restrict)
    pick_text = server.gui.add_text("Centre", initial_value="0")
    pick_btn = server.gui.add_button("Pick centre")
    undo_btn = server.gui.add_button("Undo")
    clear_btn = server.gui.add_button("Clear")
    refine_btn = server.gui.add_button("Refine")
    play_btn = server.gui.add_button("Play / Pause")
    loop_box = server.gui.add_checkbox("Loop", initial_value=ctl.loop)
    fmt = server.gui.add_dropdown("Export as", ("gif", "mp4", "none"), initial_value="gif")
    export_btn = server.gui.add_button("Export route")

    def draw_face(frame: int) -> None:
        V = (face.vertices(P[frame]) - fc) @ R.T * fscale + offset
        server.scene.add_mesh_simple(
            "/face/surface", V.astype(np.float32), face.faces, color=(230, 190, 170),
            side="double", flat_shading=False,
        )  # fmt: skip
        server.scene.add_point_cloud(
            "/face/markers", (F[frame] * fscale * marker_scale + moff).astype(np.float32),
            colors=(220, 60, 60), point_size=0.025,
        )  # fmt: skip

    def draw_cross(q2: np.ndarray) -> None:
        q = np.r_[q2[:2], 0.0]
        d = 0.06
        seg = np.array([[q - [d, 0, 0], q + [d, 0, 0]], [q - [0, d, 0], q + [0, d, 0]]])
        server.scene.add_line_segments(
            "/pad/cross", seg.astype(np.float32), colors=(0, 0, 0), thickness=0.01
        )

    def draw_level() -> None:
        lv = h.levels[ctl.level]
        cp = pad[lv.center_frames]
        server.scene.remove_by_name("/pad/links")
        if ctl.centres_by_density:  # the density image shows them; clicks still pick
            server.scene.remove_by_name("/pad/centres")
            return
        if lv.links is not None:
            i, j = np.nonzero(np.triu(lv.links, 1))
            if len(i):
                server.scene.add_line_segments(
                    "/pad/links", _segments(cp, i, j), colors=(80, 120, 220),
                    thickness=0.003 if lv.n_clusters <= 400 else 0.0015,
                )  # fmt: skip
        size = 0.035 if lv.n_clusters <= 40 else (0.025 if lv.n_clusters <= 400 else 0.014)
        server.scene.add_point_cloud(
            "/pad/centres", cp.astype(np.float32), colors=(40, 100, 200), point_size=size
        )

    def draw_route() -> None:
        for name in ("/pad/route", "/pad/keys", "/pad/guide", "/pad/candidates"):
            server.scene.remove_by_name(name)
        g = ctl.guide
        if g is not None and g is not ctl.route and len(g.frames) > 1:
            p = pad[g.frames]
            server.scene.add_line_segments(
                "/pad/guide", np.stack([p[:-1], p[1:]], 1).astype(np.float32),
                colors=(240, 150, 40), thickness=0.006,
            )  # fmt: skip
        cand = ctl.candidates()
        if len(cand):
            server.scene.add_point_cloud(
                "/pad/candidates",
                (pad[h.levels[ctl.level].center_frames[cand]] + [0, 0, 0.01]).astype(np.float32),
                colors=(40, 180, 80), point_size=0.03,
            )  # fmt: skip
        r = ctl.route
        if r is not None and len(r.frames) > 1:
            p = pad[r.frames]
            server.scene.add_line_segments(
                "/pad/route", np.stack([p[:-1], p[1:]], 1).astype(np.float32),
                colors=(220, 40, 40), thickness=0.008,
            )  # fmt: skip
        if r is not None:
            server.scene.add_point_cloud(
                "/pad/keys", (pad[r.key_frames] + [0, 0, 0.02]).astype(np.float32),
                colors=(220, 40, 40), point_size=0.04,
            )  # fmt: skip

    @serialized(server)
    def refresh(full: bool = False) -> None:
        if full:
            draw_level()
        draw_route()
        draw_face(ctl.selected_frame)
        draw_cross(pad[ctl.selected_frame])
        gui_status.content = ctl.status()
        if int(level_slider.value) != ctl.level:
            level_slider.value = ctl.level

    @server.scene.on_click()
    def _(event) -> None:
        hit = ray_plane_z0(event.ray_origin, event.ray_direction)
        if hit is None or hit[0] > 1.3:  # the face side of the scene
            return
        before = ctl.level
        ctl.pick_at(pf.to_space(hit[:2]))
        refresh(full=ctl.level != before)

    @level_slider.on_update
    def _(_e) -> None:
        if int(level_slider.value) != ctl.level:
            ctl.set_level(int(level_slider.value))
            refresh(full=True)

    @restrict_box.on_update
    def _(_e) -> None:
        ctl.set_restrict(bool(restrict_box.value))
        refresh()

    @loop_box.on_update
    def _(_e) -> None:
        ctl.loop = bool(loop_box.value)

    @pick_btn.on_click
    def _(_e) -> None:
        try:
            k = int(str(pick_text.value).strip())
        except ValueError:
            ctl.message = f"not a centre number: {pick_text.value!r}"
        else:
            ctl.pick(k)
        refresh()

    @undo_btn.on_click
    def _(_e) -> None:
        ctl.undo()
        refresh(full=True)

    @clear_btn.on_click
    def _(_e) -> None:
        ctl.clear()
        refresh()

    @refine_btn.on_click
    def _(_e) -> None:
        before = ctl.level
        ctl.refine()
        refresh(full=ctl.level != before)

    @play_btn.on_click
    def _(_e) -> None:
        ctl.playing = not ctl.playing and ctl.route is not None
        if ctl.route is None:
            ctl.message = "pick key centres first"
        refresh()

    @export_btn.on_click
    def _(_e) -> None:
        try:
            ctl.export(export_dir, str(fmt.value))
        except Exception as e:  # shown to the user, not raised into the server thread
            ctl.message = f"export failed: {e}"
        refresh()

    @serialized(server)
    def tick() -> None:
        ctl.step()
        pb = ctl.playback()
        if pb is not None:
            draw_face(ctl.selected_frame)
            draw_cross(pf.to_pad(pb.xy[ctl.play_index]))
            gui_status.content = ctl.status()

    refresh(full=True)
    attach_stop(server, Player(tick, lambda: ctl.playing, fps))
    if block:
        run_until_interrupted(server, "navigator", host)
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a navigation run or config: build and serve."""
    print(f"fxspace studio: building the expression space and hierarchy of {target} …")
    p = Path(target)
    kwargs.setdefault("export_dir", (p if p.is_dir() else Path(".")) / "navigator_export")
    return serve_navigator(load_nav_data(target), port=port, **kwargs)
