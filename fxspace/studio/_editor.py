"""The control-point editor in the browser (Hirose & Higuchi; ``pip install -e ".[viewer]"``).

``fxspace studio runs/reconstruction`` serves a viser page with:

- the dense face of the current frame (shaded surface), playing or scrubbed on a timeline;
- the control points of the current frame's segment, each with a transform gizmo:
  dragging shows the face follow live and, on release, writes a key at this frame
  (saved to ``edits.json`` in the run folder at once); a "Move control point" panel does
  the same by numbers; undo and clear;
- a toggle between the original capture, linear interpolation, the control-point model
  and the edited sequence;
- the paper's knobs (segments, control points, kernel width) and "Re-fit";
- export of the edited sequence (glTF with morph targets, or OBJ/PLY per frame) with the
  control-point data.

The state lives in :class:`EditorController` (``_edit_controller``); this module draws it
and wires the page to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.studio._edit_controller import (
    MODES,
    EditorController,
    EditorData,
    load_editor_data,
)
from fxspace.studio._server import (
    Player,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
)

__all__ = ["EditorController", "EditorData", "load_editor_data", "serve_editor", "serve"]


def _view_frame(V0: np.ndarray, names: tuple[str, ...], marker_vertex) -> np.ndarray:
    """Rows right, up, out of the face (PCA; chin → forehead up when markers are named)."""
    from fxspace.plot._navigation import face_frame

    if names and marker_vertex is not None:
        return face_frame(V0[np.asarray(marker_vertex)], names)
    return face_frame(V0)


def serve_editor(
    data: EditorData,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = True,
    block: bool = True,
    fps: float = 15.0,
    export_dir: str | Path | None = None,
):
    """Serve the editor for ``data``; ``port=0`` picks a free port. With ``block=False``
    returns ``(server, controller)`` at once (stop with ``server.stop()``)."""
    server = new_server(port, host, environment_map)
    ctl = EditorController(data)
    V0 = np.asarray(data.original[0], np.float64)
    R = _view_frame(V0, data.marker_names, data.marker_vertex)
    mu = V0.mean(0)
    scale = 2.0 / max(float(np.ptp((V0 - mu) @ R[:2].T)), 1e-12)

    def to_scene(p: np.ndarray) -> np.ndarray:
        return ((np.asarray(p, np.float64) - mu) @ R.T * scale).astype(np.float32)

    def from_scene(q) -> np.ndarray:
        return np.asarray(q, np.float64) / scale @ R + mu

    server.initial_camera.position = (0.0, 0.0, 2.8)
    server.initial_camera.look_at = (0.0, 0.0, 0.0)
    server.initial_camera.up = (0.0, 1.0, 0.0)
    out_dir = Path(export_dir) if export_dir else (data.run_dir or Path(".")) / "editor_export"

    status = server.gui.add_markdown(ctl.status())
    frame_slider = server.gui.add_slider(
        "Frame", min=0, max=ctl.n_frames - 1, step=1, initial_value=0
    )
    play_btn = server.gui.add_button("Play / Pause")
    loop_box = server.gui.add_checkbox("Loop", initial_value=True)
    mode_dd = server.gui.add_dropdown("Show", MODES, initial_value=ctl.mode)
    with server.gui.add_folder("Move control point"):
        cp_num = server.gui.add_number("Control point", initial_value=0, min=0, step=1)
        cp_delta = server.gui.add_vector3("Offset", initial_value=(0.0, 0.0, 0.0), step=0.5)
        move_btn = server.gui.add_button("Move control point")
    undo_btn = server.gui.add_button("Undo edit")
    clear_btn = server.gui.add_button("Clear edits")
    with server.gui.add_folder("Knobs (re-fit)"):
        n_seg = len(data.scene.boundaries) - 1
        n_cp = int(data.scene.segments[0].controls.shape[0])
        seg_sl = server.gui.add_slider("Segments", min=1, max=16, step=1, initial_value=n_seg)
        cp_sl = server.gui.add_slider("Control points", min=2, max=40, step=1, initial_value=n_cp)
        g_sl = server.gui.add_slider(
            "Kernel width γ", min=0.05, max=4.0, step=0.05, initial_value=data.gamma or 0.5
        )
        refit_btn = server.gui.add_button("Re-fit")
    fmt_dd = server.gui.add_dropdown("Export as", ("gltf", "obj", "ply"), initial_value="gltf")
    export_btn = server.gui.add_button("Export edited sequence")

    gizmos: dict = {"seg": -1, "handles": []}

    def draw_face(V: np.ndarray | None = None) -> None:
        V = ctl.vertices() if V is None else V
        server.scene.add_mesh_simple(
            "/face", to_scene(V), np.asarray(ctl.data.faces, np.int32), color=(230, 190, 170),
            side="double",
        )  # fmt: skip

    def draw_controls() -> None:
        seg, C = ctl.controls()
        P = to_scene(C)
        show = ctl.mode in ("edited", "control points")
        if seg != gizmos["seg"] or len(gizmos["handles"]) != len(P):
            for hd in gizmos["handles"]:
                hd.remove()
            gizmos["handles"] = []
            for k in range(len(P)):
                hd = server.scene.add_transform_controls(
                    f"/controls/cp_{k}", scale=0.08, disable_rotations=True, position=P[k],
                    line_width=1.5, depth_test=False,
                )  # fmt: skip
                _wire_gizmo(hd, k)
                gizmos["handles"].append(hd)
            gizmos["seg"] = seg
        for k, hd in enumerate(gizmos["handles"]):
            hd.position = P[k]
            hd.visible = show
        server.scene.add_point_cloud(
            "/controls/points", P, colors=(30, 90, 220), point_size=0.04, visible=show
        )

    def _wire_gizmo(hd, k: int) -> None:
        @hd.on_update
        def _(event) -> None:
            if event.phase == "end":  # released: write the key
                ctl.move_control(k, from_scene(hd.position))
                refresh()
            elif event.phase == "update":  # dragging: the face follows live, no key yet
                V = ctl.preview(k, from_scene(hd.position))
                if V is not None:
                    draw_face(V)

    @serialized(server)
    def refresh(controls: bool = True) -> None:
        draw_face()
        if controls:
            draw_controls()
        status.content = ctl.status()
        if int(frame_slider.value) != ctl.frame:
            frame_slider.value = ctl.frame

    @frame_slider.on_update
    def _(_e) -> None:
        if int(frame_slider.value) != ctl.frame:
            ctl.set_frame(int(frame_slider.value))
            refresh()

    @play_btn.on_click
    def _(_e) -> None:
        ctl.playing = not ctl.playing
        status.content = ctl.status()

    @loop_box.on_update
    def _(_e) -> None:
        ctl.loop = bool(loop_box.value)

    @mode_dd.on_update
    def _(_e) -> None:
        ctl.set_mode(str(mode_dd.value))
        refresh()

    @move_btn.on_click
    def _(_e) -> None:
        delta = np.asarray(cp_delta.value, np.float64) / scale @ R  # scene axes → data units
        ctl.nudge_control(int(cp_num.value), delta)
        refresh()

    @undo_btn.on_click
    def _(_e) -> None:
        ctl.undo()
        refresh()

    @clear_btn.on_click
    def _(_e) -> None:
        ctl.clear_edits()
        refresh()

    @refit_btn.on_click
    def _(_e) -> None:
        ctl.message = "re-fitting …"
        status.content = ctl.status()
        try:
            ctl.refit(int(seg_sl.value), int(cp_sl.value), float(g_sl.value))
        except Exception as e:  # shown to the user, not raised into the server thread
            ctl.message = f"re-fit failed: {e}"
        gizmos["seg"] = -1
        refresh()

    @export_btn.on_click
    def _(_e) -> None:
        try:
            ctl.export(out_dir, str(fmt_dd.value))
        except Exception as e:
            ctl.message = f"export failed: {e}"
        status.content = ctl.status()

    @serialized(server)
    def tick() -> None:
        ctl.step()
        refresh(controls=False)

    refresh()
    attach_stop(server, Player(tick, lambda: ctl.playing, fps))
    if block:
        run_until_interrupted(server, "editor", host)
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a reconstruction run (or its config)."""
    return serve_editor(load_editor_data(target), port=port, **kwargs)
