"""Mesh-IK studio (Park, Kang & Kwon's interactive system) in the browser (viser).

``serve_ik(TARGET)`` (TARGET: a ``.glb``, a ``mesh_ik`` run folder or config) serves a
page with the skinned mesh shaded; as in the paper, "one or more markers are selected on
the surface of the model and their target positions are set":

- **click on the surface** to add a marker on the clicked triangle (only triangles facing
  the camera, the paper's visibility test; or type a triangle index and press
  *Add marker*);
- each marker's target is a **draggable gizmo**; the mesh follows on every drag event
  (one warm-started `fxspace.solve_ik` per event), or type a target and press
  *Move target*;
- *Solver*: Levenberg–Marquardt on the analytic Jacobian (the default), or the paper's
  gradient path, BFGS on the factored gradient of eq. (13) (or on eq. (9));
- *Remove marker*; *Play / Pause* plays the mesh's own animation and tracks it with the
  current markers (their targets follow the animated surface, IK warm-started per frame);
- *BVH take* + *Load take*: a BVH file (any skeleton with nameable joints: CMU, Bandai,
  Mixamo, VRM) retargeted onto the mesh (`fxspace.mesh.retarget`); *Play / Pause* plays
  it, the scaled source's joints drawn red, the character's corresponded joints blue, the
  feet in contact green (``serve_ik(…, take=PATH)`` loads one at start);
- *Export BVH* writes the current pose, or the tracked frames, as BVH
  (`fxspace.io.write_ik_bvh`); *Export glTF* writes them with the mesh as an
  animated ``.glb`` (`fxspace.io.write_ik_gltf`). A file of that name that this app did
  not write (the user's own ``ik_pose.bvh``) is kept: the export goes beside it
  (``ik_pose-2.bvh``), as the status line says.

The state and actions live in `IKController` (``_ik_controller``, plain Python,
testable without a browser); `IKView` draws it and `serve_ik` wires the page to it.

Example: ``server, ctl = serve_ik("CesiumMan.glb", port=0, block=False)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.studio._ik_controller import IK_SOLVERS, IKController, load_ik_mesh
from fxspace.studio._server import (
    Player,
    ServeOptions,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
    status_markdown,
)

__all__ = ["IKController", "IKView", "load_ik_mesh", "serve_ik", "status_text"]


def status_text(st: dict) -> str:
    """The status panel's Markdown from `IKController.status` (data in, text out)."""
    cons = ", ".join(f"{i}: {k}" for i, k in st["constraints"].items())
    return status_markdown(
        f"Markers: {st['markers']}",
        [
            f"Constraints: {cons}" if cons else "",
            f"{'Playing' if st['playing'] else 'Paused'} t = {st['time']:.2f} s",
            f"Solver: {IK_SOLVERS[st['solver']]}" if "solver" in st else "",
        ],
        st["message"],
    )


class IKView:
    """The IK studio's page: the shaded mesh, the markers and targets (with a draggable
    gizmo per target) and the controls, each wired to one `IKController` method."""

    def __init__(self, server, ctl: IKController, export_path, gltf_path):
        self.server, self.ctl = server, ctl
        lo, hi = ctl.mesh.vertices.min(0), ctl.mesh.vertices.max(0)
        centre, self.size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
        server.initial_camera.position = tuple(centre + np.array([0.0, 0.0, 1.5 * self.size]))
        server.initial_camera.look_at = tuple(centre)
        server.initial_camera.up = (0.0, 1.0, 0.0)
        self.gizmos: list = []
        gui = server.gui
        self.gui_status = gui.add_markdown(status_text(ctl.status()))
        self.tri_text = gui.add_text("Triangle", initial_value="0")
        self.add_btn = gui.add_button("Add marker")
        self.idx_text = gui.add_text("Marker", initial_value="0")
        self.tgt_text = gui.add_text("Target x y z", initial_value="")
        self.move_btn = gui.add_button("Move target")
        self.rm_btn = gui.add_button("Remove marker")
        self.solver = gui.add_dropdown("Solver", tuple(IK_SOLVERS), initial_value=ctl.solver)
        self.kind = gui.add_dropdown("Constraint", ("normal", "floor", "none"))
        self.cons_btn = gui.add_button("Constrain marker")
        self.take_text = gui.add_text("BVH take", initial_value="")
        self.take_btn = gui.add_button("Load take")
        self.play_btn = gui.add_button("Play / Pause", disabled=ctl.animation is None)
        self.export_btn = gui.add_button("Export BVH")
        self.gltf_btn = gui.add_button("Export glTF")
        self.redraw = serialized(server)(self._redraw)
        self._wire(export_path, gltf_path)

    def draw_mesh(self) -> None:
        h = self.server.scene.add_mesh_simple(
            "/mesh", self.ctl.vertices.astype(np.float32), self.ctl.faces, color=(200, 170, 140)
        )
        h.on_click(self.on_mesh_click)

    def draw_markers(self, gizmos: bool = True) -> None:
        scene, ctl = self.server.scene, self.ctl
        pts = ctl.marker_points().astype(np.float32)
        if len(pts):
            scene.add_point_cloud(
                "/markers", pts, colors=(30, 90, 220), point_size=0.01 * self.size
            )
            scene.add_point_cloud(
                "/targets",
                ctl.targets.astype(np.float32),
                colors=(220, 40, 40),
                point_size=0.012 * self.size,
            )
        else:
            scene.remove_by_name("/markers")
            scene.remove_by_name("/targets")
        if not gizmos:
            return
        for g in self.gizmos:
            g.remove()
        self.gizmos = []
        for i, p in enumerate(ctl.targets):
            g = scene.add_transform_controls(
                f"/target_{i}", scale=0.08 * self.size, disable_rotations=True, position=tuple(p)
            )
            g.on_update(lambda _e, i=i, g=g: self.on_drag(i, g))
            self.gizmos.append(g)

    def draw_take(self) -> None:
        """The loaded take's frame: source joints (red), the character's corresponded
        joints (blue), the feet in contact (green)."""
        ov = self.ctl.take_overlay()
        if ov is None:
            return
        src, char, contact = (np.asarray(a) for a in ov)
        sc, size = self.server.scene, self.size
        sc.add_point_cloud("/take/source", src.astype(np.float32), colors=(220, 40, 40),
                           point_size=0.02 * size)  # fmt: skip
        sc.add_point_cloud("/take/character", char.astype(np.float32), colors=(30, 90, 220),
                           point_size=0.015 * size)  # fmt: skip
        feet = char[contact] if contact.any() else np.zeros((0, 3))
        if len(feet):
            sc.add_point_cloud("/take/contacts", feet.astype(np.float32), colors=(40, 200, 60),
                               point_size=0.035 * size)  # fmt: skip
        else:
            sc.remove_by_name("/take/contacts")

    def load_take(self) -> None:
        self.ctl.load_take(str(self.take_text.value))
        self.play_btn.disabled = False

    def _redraw(self, gizmos: bool = True) -> None:
        self.draw_mesh()
        self.draw_markers(gizmos)
        self.draw_take()
        self.gui_status.content = status_text(self.ctl.status())

    def on_mesh_click(self, e) -> None:
        self.guarded(lambda: self.ctl.pick(e.ray_origin, e.ray_direction))

    def on_drag(self, i: int, g) -> None:
        self.ctl.move_target(i, np.asarray(g.position))
        self.redraw(gizmos=False)

    def guarded(self, action) -> None:
        """Run a controller action; a user error becomes the status line; redraw."""
        try:
            action()
        except (FxspaceError, ValueError, OSError) as err:
            self.ctl.message = str(err)
        self.redraw()

    def _add_marker(self, e) -> None:
        cam = e.client.camera if e.client is not None else None
        view = None if cam is None else np.asarray(cam.look_at) - np.asarray(cam.position)
        self.ctl.add_marker(int(str(self.tri_text.value).strip()), view_dir=view)

    def _move_target(self) -> None:
        xyz = [float(x) for x in str(self.tgt_text.value).replace(",", " ").split()]
        if len(xyz) != 3:
            raise ValueError(f"target needs three numbers 'x y z', got {self.tgt_text.value!r}")
        self.ctl.move_target(self._marker(), xyz)

    def _marker(self) -> int:
        return int(str(self.idx_text.value).strip())

    def _wire(self, export_path, gltf_path) -> None:
        ctl = self.ctl
        self.add_btn.on_click(lambda e: self.guarded(lambda: self._add_marker(e)))
        self.move_btn.on_click(lambda _e: self.guarded(self._move_target))
        self.rm_btn.on_click(lambda _e: self.guarded(lambda: ctl.remove_marker(self._marker())))
        self.cons_btn.on_click(
            lambda _e: self.guarded(
                lambda: ctl.add_constraint(self._marker(), str(self.kind.value))
            )
        )
        self.solver.on_update(
            lambda _e: self.guarded(lambda: ctl.set_solver(str(self.solver.value)))
        )
        self.take_btn.on_click(lambda _e: self.guarded(self.load_take))
        self.play_btn.on_click(lambda _e: self.guarded(ctl.toggle_play))
        self.export_btn.on_click(lambda _e: self.guarded(lambda: ctl.export_bvh(export_path)))
        self.gltf_btn.on_click(lambda _e: self.guarded(lambda: ctl.export_gltf(gltf_path)))


def serve_ik(
    target,
    port: int = 8080,
    *,
    open_browser: bool = False,
    host: str = "127.0.0.1",
    block: bool = True,
    environment_map: bool = False,
    export_path: str | Path = "ik_pose.bvh",
    gltf_path: str | Path | None = None,
    options: ServeOptions | None = None,
    take: str | Path | None = None,
):
    """Serve the IK studio for ``target`` (see `load_ik_mesh`); ``port=0`` picks a free
    port (``server.get_port()``), or pass `options`, a `ServeOptions`, which wins over
    the keywords. With ``block=False`` returns ``(server, controller)`` at once (stop with
    ``server.stop()``; the page's `IKView` is ``server.fxspace_view``). *Export glTF*
    writes `gltf_path` (default: `export_path` with the suffix ``.glb``). `take`: a BVH
    file retargeted onto the mesh at start (`IKController.load_take`)."""
    o = options or ServeOptions(port, host, 30.0, block, environment_map)
    mesh, anim = load_ik_mesh(target)
    ctl = IKController(mesh, anim, fps=o.fps)
    server = new_server(o.port, o.host, o.environment_map)
    if gltf_path is None:
        bvh = Path(export_path)
        gltf_path = bvh.with_name(bvh.name.removesuffix(".gz").removesuffix(".bvh") + ".glb")
    view = IKView(server, ctl, export_path, gltf_path)
    server.fxspace_view = view
    if take is not None:
        view.take_text.value = str(take)
        try:
            view.load_take()
        except BaseException:
            server.stop()
            raise

    @serialized(server)
    def tick() -> None:
        ctl.step()
        view._redraw(gizmos=False)

    view.redraw()
    attach_stop(server, Player(tick, lambda: ctl.playing and bool(server.get_clients()), ctl.fps))
    url = f"http://{o.host}:{server.get_port()}"
    if open_browser:
        import webbrowser

        webbrowser.open(url)
    if not o.block:
        return server, ctl
    run_until_interrupted(server, "IK studio", o.host)
    return server, ctl
