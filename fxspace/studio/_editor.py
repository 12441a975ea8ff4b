"""The control-point editor in the browser (Hirose & Higuchi; ``pip install -e ".[viewer]"``).

``fxspace studio runs/reconstruction`` serves a viser page with:

- the current frame, playing or scrubbed on a timeline, as a real head (the ICT Face
  Model's blend shapes, `fxspace.face`, with eyes and teeth; its weights and head motion
  solved from the markers, which ride on the shown surface, so an edit changes the head
  at once) or as the modelled dense surface itself; the weights' curves of the chosen
  shapes over the sequence (the edited sequence's and the model's);
- the control points of the current frame's segment, each with a transform gizmo:
  dragging shows the face follow live and, on release, writes a key on the face at this
  frame — any frame, segment boundaries included (saved to ``edits.json`` in the run
  folder at once); a "Move control point" panel does the same by numbers; undo, redo and
  clear; the status shows the keys on a timeline;
- a toggle between the original capture, linear interpolation, the control-point model
  and the edited sequence;
- the paper's knobs (segments, control points, kernel width) and "Re-fit";
- export of the edited sequence (glTF with morph targets, or OBJ/PLY per frame) with the
  control-point data, and the head carrying the edits (``head.glb``: the rig's morph
  targets with the weight animation; ``head_weights.csv``).

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
    Player,
    ServeOptions,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
    status_markdown,
    studio_face,
)

__all__ = [
    "EditorController",
    "EditorData",
    "EditorView",
    "load_editor_data",
    "serve_editor",
    "serve",
    "status_text",
    "timeline",
]


def timeline(st: dict, width: int = 60) -> str:
    """One line of text from `EditorController.status`: ``|`` segment boundaries, ``◆``
    key frames, ``▲`` the current frame, ``·`` other frames (``width`` cells over the
    scene)."""
    T = st["n_frames"]
    cells = ["·"] * min(width, T)
    n = len(cells)

    def cell(f: int) -> int:
        return min(n - 1, int(f * n / T))

    for b in st["boundaries"]:
        cells[cell(b)] = "|"
    for f in st["key_frames"]:
        cells[cell(f)] = "◆"
    cells[cell(st["frame"])] = "▲"
    return "".join(cells)


def status_text(st: dict) -> str:
    """The status panel's Markdown from `EditorController.status` (data in, text out)."""
    kf = st["key_frames"]
    a, b = st["span"]
    return status_markdown(
        f"Frame {st['frame']}",
        [
            f"Showing: {st['mode']}",
            f"Edit keys: {st['keys']}",
            f"Keys at frames: {', '.join(map(str, kf)) if kf else 'none'}",
            f"`{timeline(st)}`",
            f"Edited vs model here: {st['edit_diff']:.3f} max",
            "Playing" if st["playing"] else "Paused",
        ],
        st["message"],
        after_title=f" of {st['n_frames'] - 1} — segment {st['segment']} (frames {a}–{b})",
    )


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
        self.cp_labels: list = []  # each gizmo's index, as the "Move control point" panel takes it
        self.shown_segment = -1
        self.head = ctl.face
        self.shown_head: np.ndarray | None = None  # the head's vertices last drawn
        self.curves = None
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
        self.status = gui.add_markdown(status_text(ctl.status()))
        self.frame_slider = gui.add_slider(
            "Frame", min=0, max=ctl.n_frames - 1, step=1, initial_value=0
        )
        self.play_btn = gui.add_button("Play / Pause")
        self.loop_box = gui.add_checkbox("Loop", initial_value=True)
        self.mode_dd = gui.add_dropdown("Show", MODES, initial_value=ctl.mode)
        kinds = ("head", "surface") if self.head is not None else ("surface",)
        self.face_dd = gui.add_dropdown("Face", kinds, initial_value=kinds[0])
        self.dots_box = gui.add_checkbox("Markers on the face", initial_value=False)
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
        if ctl.has_rig:
            self.curve_dd = gui.add_dropdown("Weight curves", self._curve_choices(),
                                             initial_value="most edited")  # fmt: skip
            self.curve_dd.on_update(lambda _e: self.draw_curves())
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
        self.dots_box.on_update(act(lambda: None))
        self.move_btn.on_click(act(self._move_by_numbers))
        self.undo_btn.on_click(act(ctl.undo))
        self.redo_btn.on_click(act(ctl.redo))
        self.clear_btn.on_click(act(ctl.clear_edits))
        self.refit_btn.on_click(act(self._refit))
        self.export_btn.on_click(act(self._export))

    def _curve_choices(self) -> tuple[str, ...]:
        return ("most edited", "most active", *self.ctl.face.names)

    def curve_shapes(self) -> list[int]:
        """The shapes whose weight curves are drawn: the chosen one, or the three that the
        edits change most / that move most in the edited sequence."""
        ctl, pick = self.ctl, str(self.curve_dd.value)
        names = list(ctl.face.names)
        if pick in names:
            return [names.index(pick)]
        W = np.nan_to_num(ctl.head_weights("edited"))
        if pick == "most edited" and ctl.keys:
            score = np.abs(W - np.nan_to_num(ctl.head_weights("control points"))).max(0)
        else:
            score = np.ptp(W, axis=0)
        return [int(k) for k in np.argsort(-score)[:3]]

    def draw_curves(self) -> None:
        """The chosen shapes' weights over the sequence: edited (solid) and the model's
        (dashed), the frame axis matching the timeline."""
        if not self.ctl.has_rig:
            return
        ctl = self.ctl
        ks = self.curve_shapes()
        We, Wm = ctl.head_weights("edited"), ctl.head_weights("control points")
        x = np.arange(ctl.n_frames, dtype=np.float64)
        data, series = [x], [{"label": "frame"}]
        palette = ("#d62728", "#1f77b4", "#2ca02c")
        for c, k in enumerate(ks):
            name = ctl.face.names[k]
            data += [We[:, k].astype(np.float64), Wm[:, k].astype(np.float64)]
            series += [{"label": f"{name} (edited)", "stroke": palette[c % 3], "width": 2},
                       {"label": f"{name} (model)", "stroke": palette[c % 3], "width": 1,
                        "dash": [4, 4]}]  # fmt: skip
        if self.curves is not None:
            self.curves.remove()
        self.curves = self.server.gui.add_uplot(
            tuple(data), tuple(series), title="Expression weights", aspect=1.6,
            **curve_axes(ctl.n_frames),
        )  # fmt: skip

    def _move_by_numbers(self) -> None:
        delta = np.asarray(self.cp_delta.value, np.float64) / self.scale @ self.R
        self.ctl.nudge_control(int(self.cp_num.value), delta)

    def _refit(self) -> None:
        self.ctl.message = "re-fitting …"
        self.status.content = status_text(self.ctl.status())
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
        """The shown frame: the modelled surface itself, or the head (the face the
        navigator shows: the rig, else the template) driven by the capture's markers
        moved as the surface under them moved (`EditorController.head_markers`: the
        edits show on the head at once)."""
        V = self.ctl.vertices() if V is None else V
        d = self.ctl.data
        dots = None
        if self.head is not None and str(self.face_dd.value) == "head":
            dots = self.ctl.head_markers(V)
            self.shown_head = self.head.vertices(dots)
            parts = [(f"/face/{n}", v, f, c) for n, v, f, c in self.head.meshes(
                self.shown_head)]  # fmt: skip
        else:
            parts = [("/face/surface", V, np.asarray(d.faces, np.int32), (230, 190, 170))]
        for name in set(self.face_nodes) - {p[0] for p in parts}:
            self.face_nodes.pop(name).remove()
        for name, v, f, colour in parts:
            self.face_nodes[name] = self.server.scene.add_mesh_simple(
                name, self.to_scene(v), np.asarray(f, np.int32), color=colour, side="double"
            )
        if dots is not None and self.dots_box.value:  # the markers, as dots on the head
            self.server.scene.add_point_cloud(
                "/face/dots", self.to_scene(dots) + np.float32([0, 0, 0.01]),
                colors=(220, 60, 60), point_size=0.02,
            )  # fmt: skip
        else:
            self.server.scene.remove_by_name("/face/dots")

    def draw_controls(self) -> None:
        seg, C = self.ctl.controls()
        P = self.to_scene(C)
        show = self.ctl.mode in ("edited", "control points")
        if seg != self.shown_segment or len(self.handles) != len(P):
            for hd in self.cp_labels + self.handles:  # a label before its gizmo
                hd.remove()
            self.handles, self.cp_labels = [], []
            for k in range(len(P)):
                hd = self.server.scene.add_transform_controls(
                    f"/controls/cp_{k}", scale=0.08, disable_rotations=True, position=P[k],
                    line_width=1.5, depth_test=False,
                )  # fmt: skip
                # the index the "Move control point" panel takes, riding on the gizmo
                self.cp_labels.append(self.server.scene.add_label(
                    f"/controls/cp_{k}/index", gizmo_label(k), position=(0.012, 0.012, 0.0),
                    font_screen_scale=1.2, anchor="bottom-left",
                ))  # fmt: skip
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
            self.draw_curves()
        self.status.content = status_text(self.ctl.status())
        if int(self.frame_slider.value) != self.ctl.frame:
            self.frame_slider.value = self.ctl.frame


def curve_axes(n_frames: int) -> dict:
    """uPlot options of the weight chart: a numeric x axis labelled "frame" over the
    sequence (uPlot reads x as a time in seconds since 1970 unless told otherwise, and
    printed "12:00am 1/1/70"), and the weight (0 to 1) on y."""
    return {
        "scales": {"x": {"time": False, "range": [0.0, float(max(n_frames - 1, 1))]},
                   "y": {"range": [0.0, 1.05]}},  # room for the top tick and a curve at 1
        "axes": ({"label": "frame", "scale": "x"}, {"label": "weight", "scale": "y"}),
    }  # fmt: skip


def gizmo_label(k: int) -> str:
    """The text beside control point ``k``'s gizmo: the number the panel moves it by."""
    return f"#{k}"


def _head_of(data: EditorData, head: str | Path | None = "face/ict"):
    """``(face, note)``: the head for the run's markers (`studio_face`: the rig at
    ``head``, else the template head), or ``(None, why)`` when the run kept no markers or
    no head can be fitted (the modelled surface is shown instead)."""
    if data.markers is None or data.marker_vertex is None:
        return None, "the run kept no markers: the surface is shown"
    try:
        return studio_face(data.markers[0], data.marker_names or None, head)
    except Exception as e:  # the modelled surface is shown instead, saying why
        return None, f"no head ({e}): the surface is shown"


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
    head: str | Path | None = "face/ict",
):
    """Serve the editor for ``data``; ``port=0`` picks a free port (or pass `options`, a
    `ServeOptions`, which wins over the keywords). With ``block=False`` returns
    ``(server, controller)`` at once (stop with ``server.stop()``); the page's
    `EditorView` is ``server.fxspace_view``. ``head``: the rig the head is (a path, or one
    under the data root; the ICT Face Model by default; ``None``: the template head)."""
    o = options or ServeOptions(port, host, fps, block, environment_map)
    face, note = _head_of(data, head)
    server = new_server(o.port, o.host, o.environment_map)
    ctl = EditorController(data, face)
    out_dir = Path(export_dir) if export_dir else (data.run_dir or Path(".")) / "editor_export"
    view = EditorView(server, ctl, out_dir)
    view.face_note = server.gui.add_markdown(f"_Face: {note}_")
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
    """``fxspace studio TARGET`` for a reconstruction run (or its config); the head is the
    rig its config names (``head``, the ICT Face Model by default)."""
    data = load_editor_data(target)
    if data.run_dir is not None and (data.run_dir / "config.toml").is_file():
        from fxspace.config import load_toml

        kwargs.setdefault("head", load_toml(data.run_dir / "config.toml").get("head", "face/ict")
                          or None)  # fmt: skip
    return serve_editor(data, port=port, **kwargs)
