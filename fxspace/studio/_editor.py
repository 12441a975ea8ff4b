"""The control-point editor in the browser (Hirose & Higuchi; ``pip install -e ".[viewer]"``).

``fxspace studio runs/reconstruction`` serves a viser page with:

- the dense face of the current frame (shaded surface), playing or scrubbed on a timeline;
- the control points of the current frame's segment, each with a transform gizmo:
  dragging shows the face follow live and, on release, writes a key on the face at this
  frame — any frame, segment boundaries included (saved to ``edits.json`` in the run
  folder at once); a "Move control point" panel does the same by numbers; undo, redo and
  clear; the status shows the keys on a timeline;
- a toggle between the original capture, linear interpolation, the control-point model
  and the edited sequence;
- the paper's knobs (segments, control points, kernel width) and "Re-fit";
- export of the edited sequence (glTF with morph targets, or OBJ/PLY per frame) with the
  control-point data.

The state lives in `EditorController` (``_edit_controller``); `EditorView` draws it and
wires the page to it (its `EditorView.on_gizmo` is what a gizmo drag calls).
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
    DenseFace,
    Player,
    ServeOptions,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
)

__all__ = [
    "EditorController",
    "EditorData",
    "EditorView",
    "load_editor_data",
    "serve_editor",
    "serve",
]


def _view_frame(V0: np.ndarray, names: tuple[str, ...], marker_vertex) -> np.ndarray:
    """Rows right, up, out of the face (PCA; chin → forehead up when markers are named)."""
    from fxspace.plot import face_frame

    if names and marker_vertex is not None:
        return face_frame(V0[np.asarray(marker_vertex)], names)
    return face_frame(V0)


class EditorView:
    """The page of one editor: widgets wired to an `EditorController`; ``handles`` are
    the control points' gizmos of the shown segment."""

    def __init__(self, server, ctl: EditorController, export_dir: Path):
        self.server, self.ctl, self.export_dir = server, ctl, export_dir
        V0 = np.asarray(ctl.data.original[0], np.float64)
        self.R = _view_frame(V0, ctl.data.marker_names, ctl.data.marker_vertex)
        self.mu = V0.mean(0)
        self.scale = 2.0 / max(float(np.ptp((V0 - self.mu) @ self.R[:2].T)), 1e-12)
        self.handles: list = []
        self.shown_segment = -1
        self.head = _head_of(ctl.data)
        self.face_nodes: dict = {}
        server.initial_camera.position = (0.0, 0.0, 2.8)
        server.initial_camera.look_at = (0.0, 0.0, 0.0)
        server.initial_camera.up = (0.0, 1.0, 0.0)
        self.refresh = serialized(server)(self._refresh)
        self._build()

    def to_scene(self, p) -> np.ndarray:
        return ((np.asarray(p, np.float64) - self.mu) @ self.R.T * self.scale).astype(np.float32)

    def from_scene(self, q) -> np.ndarray:
        return np.asarray(q, np.float64) / self.scale @ self.R + self.mu

    def _build(self) -> None:
        gui, ctl = self.server.gui, self.ctl
        self.status = gui.add_markdown(ctl.status())
        self.frame_slider = gui.add_slider(
            "Frame", min=0, max=ctl.n_frames - 1, step=1, initial_value=0
        )
        self.play_btn = gui.add_button("Play / Pause")
        self.loop_box = gui.add_checkbox("Loop", initial_value=True)
        self.mode_dd = gui.add_dropdown("Show", MODES, initial_value=ctl.mode)
        kinds = ("head", "surface") if self.head is not None else ("surface",)
        self.face_dd = gui.add_dropdown("Face", kinds, initial_value=kinds[0])
        with gui.add_folder("Move control point"):
            self.cp_num = gui.add_number("Control point", initial_value=0, min=0, step=1)
            self.cp_delta = gui.add_vector3("Offset", initial_value=(0.0, 0.0, 0.0), step=0.5)
            self.move_btn = gui.add_button("Move control point")
        self.undo_btn = gui.add_button("Undo edit")
        self.redo_btn = gui.add_button("Redo edit")
        self.clear_btn = gui.add_button("Clear edits")
        with gui.add_folder("Knobs (re-fit)"):
            sc = ctl.data.scene
            self.seg_sl = gui.add_slider(
                "Segments", min=1, max=16, step=1, initial_value=len(sc.boundaries) - 1
            )
            self.cp_sl = gui.add_slider(
                "Control points", min=2, max=40, step=1,
                initial_value=int(sc.segments[0].controls.shape[0]),
            )  # fmt: skip
            self.g_sl = gui.add_slider(
                "Kernel width γ", min=0.05, max=4.0, step=0.05,
                initial_value=ctl.data.gamma or 0.5,
            )  # fmt: skip
            self.refit_btn = gui.add_button("Re-fit")
        self.fmt_dd = gui.add_dropdown("Export as", ("gltf", "obj", "ply"), initial_value="gltf")
        self.export_btn = gui.add_button("Export edited sequence")
        self._wire()

    def _wire(self) -> None:
        ctl = self.ctl

        def act(fn):
            def cb(_e) -> None:
                fn()
                self.refresh()

            return cb

        self.frame_slider.on_update(act(lambda: ctl.set_frame(int(self.frame_slider.value))))
        self.play_btn.on_click(act(lambda: setattr(ctl, "playing", not ctl.playing)))
        self.loop_box.on_update(act(lambda: setattr(ctl, "loop", bool(self.loop_box.value))))
        self.mode_dd.on_update(act(lambda: ctl.set_mode(str(self.mode_dd.value))))
        self.face_dd.on_update(act(lambda: None))
        self.move_btn.on_click(act(self._move_by_numbers))
        self.undo_btn.on_click(act(ctl.undo))
        self.redo_btn.on_click(act(ctl.redo))
        self.clear_btn.on_click(act(ctl.clear_edits))
        self.refit_btn.on_click(act(self._refit))
        self.export_btn.on_click(act(self._export))

    def _move_by_numbers(self) -> None:
        delta = np.asarray(self.cp_delta.value, np.float64) / self.scale @ self.R
        self.ctl.nudge_control(int(self.cp_num.value), delta)

    def _refit(self) -> None:
        self.ctl.message = "re-fitting …"
        self.status.content = self.ctl.status()
        try:
            self.ctl.refit(int(self.seg_sl.value), int(self.cp_sl.value), float(self.g_sl.value))
        except Exception as e:  # shown to the user, not raised into the server thread
            self.ctl.message = f"re-fit failed: {e}"
        self.shown_segment = -1

    def _export(self) -> None:
        try:
            self.ctl.export(self.export_dir, str(self.fmt_dd.value))
        except Exception as e:
            self.ctl.message = f"export failed: {e}"

    def on_gizmo(self, k: int, phase: str, scene_position) -> None:
        """A drag of control point ``k``'s gizmo (scene coordinates): ``"update"`` shows
        the face follow live, ``"end"`` (release) writes the key at the current frame."""
        p = self.from_scene(scene_position)
        if phase == "end":
            self.ctl.move_control(k, p)
            self.refresh()
        elif phase == "update":
            V = self.ctl.preview(k, p)
            if V is not None:
                self.draw_face(V)

    def draw_face(self, V: np.ndarray | None = None) -> None:
        """The shown frame: the modelled surface itself, or the studio's head (the face
        the navigator shows, `DenseFace`) driven by the capture's markers moved as the
        surface under them moved (so the edits show on the head too)."""
        V = self.ctl.vertices() if V is None else V
        d = self.ctl.data
        if self.head is not None and str(self.face_dd.value) == "head":
            t = self.ctl.frame
            mk = d.markers[t] + (V - d.original[t])[np.asarray(d.marker_vertex)]
            parts = [(f"/face/{n}", v, f, c) for n, v, f, c in self.head.meshes(
                self.head.vertices(mk))]  # fmt: skip
        else:
            parts = [("/face/surface", V, np.asarray(d.faces, np.int32), (230, 190, 170))]
        for name in set(self.face_nodes) - {p[0] for p in parts}:
            self.face_nodes.pop(name).remove()
        for name, v, f, colour in parts:
            self.face_nodes[name] = self.server.scene.add_mesh_simple(
                name, self.to_scene(v), np.asarray(f, np.int32), color=colour, side="double"
            )

    def draw_controls(self) -> None:
        seg, C = self.ctl.controls()
        P = self.to_scene(C)
        show = self.ctl.mode in ("edited", "control points")
        if seg != self.shown_segment or len(self.handles) != len(P):
            for hd in self.handles:
                hd.remove()
            self.handles = []
            for k in range(len(P)):
                hd = self.server.scene.add_transform_controls(
                    f"/controls/cp_{k}", scale=0.08, disable_rotations=True, position=P[k],
                    line_width=1.5, depth_test=False,
                )  # fmt: skip
                hd.on_update(self._gizmo_callback(hd, k))
                self.handles.append(hd)
            self.shown_segment = seg
        for k, hd in enumerate(self.handles):
            hd.position = P[k]
            hd.visible = show
        self.server.scene.add_point_cloud(
            "/controls/points", P, colors=(30, 90, 220), point_size=0.04, visible=show
        )

    def _gizmo_callback(self, hd, k: int):
        def cb(event) -> None:
            self.on_gizmo(k, str(event.phase), hd.position)

        return cb

    def _refresh(self, controls: bool = True) -> None:
        self.draw_face()
        if controls:
            self.draw_controls()
        self.status.content = self.ctl.status()
        if int(self.frame_slider.value) != self.ctl.frame:
            self.frame_slider.value = self.ctl.frame


def _head_of(data: EditorData):
    """The studio's head (`DenseFace`) for the run's markers, or None (no markers kept,
    or the head cannot be fitted)."""
    if data.markers is None or data.marker_vertex is None:
        return None
    try:
        return DenseFace(data.markers[0], 2500, data.marker_names or None)
    except Exception:  # the modelled surface is shown instead
        return None


def serve_editor(
    data: EditorData,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = False,
    block: bool = True,
    fps: float = 15.0,
    export_dir: str | Path | None = None,
    options: ServeOptions | None = None,
):
    """Serve the editor for ``data``; ``port=0`` picks a free port (or pass `options`, a
    `ServeOptions`, which wins over the keywords). With ``block=False`` returns
    ``(server, controller)`` at once (stop with ``server.stop()``); the page's
    `EditorView` is ``server.fxspace_view``."""
    o = options or ServeOptions(port, host, fps, block, environment_map)
    server = new_server(o.port, o.host, o.environment_map)
    ctl = EditorController(data)
    out_dir = Path(export_dir) if export_dir else (data.run_dir or Path(".")) / "editor_export"
    view = EditorView(server, ctl, out_dir)
    server.fxspace_view = view

    @serialized(server)
    def tick() -> None:
        ctl.step()
        view._refresh(controls=False)

    view.refresh()
    attach_stop(server, Player(tick, lambda: ctl.playing, o.fps))
    if o.block:
        run_until_interrupted(server, "editor", o.host)
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a reconstruction run (or its config)."""
    return serve_editor(load_editor_data(target), port=port, **kwargs)
