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
- *Remove marker*; *Play / Pause* plays the mesh's own animation and tracks it with the
  current markers (their targets follow the animated surface, IK warm-started per frame);
- *Export BVH* writes the current pose, or the tracked frames, as BVH
  (`fxspace.io.write_ik_bvh`); *Export glTF* writes them with the mesh as an
  animated ``.glb`` (`fxspace.io.write_ik_gltf`).

The state and actions live in `IKController` (plain Python, testable without a
browser); `serve_ik` draws and wires it.

Example: ``server, ctl = serve_ik("CesiumMan.glb", port=0, block=False)``.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.mesh import (
    MarkerSet,
    Pose,
    animation_vertices,
    ik_constraints,
    ik_model,
    marker_positions,
    normal_constraint,
    plane_contact,
    pose_vertices,
    solve_ik,
    triangle_normals,
)
from fxspace.results import RESULTS
from fxspace.studio._server import (
    Player,
    ServeOptions,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
)

__all__ = ["IKController", "IKView", "load_ik_mesh", "serve_ik"]


def load_ik_mesh(target):
    """The skinned mesh of ``target``: a ``.glb``/``.gltf`` file, a ``mesh_ik`` config or
    run folder (its first mesh), or an already-read `fxspace.SkinnedMesh`;
    returns ``(mesh, animation name or None)``."""
    from fxspace.io import read_gltf
    from fxspace.mesh import SkinnedMesh

    if isinstance(target, SkinnedMesh):
        return target, (target.animation_names[0] if target.animations else None)
    p = Path(target)
    if p.suffix.lower() in (".glb", ".gltf"):
        mesh = read_gltf(p)
        return mesh, (mesh.animation_names[0] if mesh.animations else None)
    from fxspace.data import data_path

    if not (p.is_dir() or p.is_file()):
        raise FxspaceError(f"{target}: not a .glb, a mesh_ik run folder or a mesh_ik config")
    from fxspace.pipelines import resolve_config

    spec = resolve_config(p, experiment="mesh_ik")[0].config.meshes[0]
    stem, _, anim = spec.partition(":")
    mesh = read_gltf(data_path("mesh", f"{stem}.glb"))
    return mesh, (anim or (mesh.animation_names[0] if mesh.animations else None))


class IKController:
    """The IK studio's state and actions, independent of any UI.

    ``markers`` (triangle, barycentric) and ``targets`` ``(K, 3)``; ``pose`` the current
    `fxspace.Pose`; ``vertices`` the posed mesh; ``recorded`` the poses tracked
    while playing; ``message`` the last status line.
    """

    def __init__(self, mesh, animation: str | None = None, fps: float = 30.0):
        self.mesh = mesh
        self.animation = animation
        self.fps = fps
        self.faces = np.asarray(mesh.faces)
        nj = mesh.num_joints
        self.pose = Pose(jnp.zeros((nj, 3)), jnp.zeros(3))
        self.triangles: list[int] = []
        self.barycentric: list[np.ndarray] = []
        self.targets = np.zeros((0, 3))
        self.recorded: list[Pose] = []
        self.time = 0.0
        self.playing = False
        self.last_result = None
        self.message = "click the mesh (or type a triangle) to add a marker"
        self.constraints: dict[int, str] = {}  # marker index → "normal" | "floor"
        self.constraint_weight = {"normal": 0.1, "floor": 100.0}
        self._model = None
        self._posed = jax.jit(lambda p: pose_vertices(mesh, p))
        self.vertices = np.asarray(self._posed(self.pose))
        self.floor_height = float(self.vertices[:, 1].min())  # the rest pose's lowest point
        self._normals = None
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ markers
    @property
    def num_markers(self) -> int:
        return len(self.triangles)

    def marker_set(self) -> MarkerSet:
        return MarkerSet(
            jnp.asarray(np.asarray(self.triangles, np.int32)),
            jnp.asarray(np.asarray(self.barycentric).reshape(-1, 3)),
        )

    def marker_points(self) -> np.ndarray:
        """Current marker positions on the posed mesh ``(K, 3)``."""
        if not self.triangles:
            return np.zeros((0, 3))
        return np.asarray(marker_positions(self.vertices, self.faces, self.marker_set()))

    def visible(self, view_dir) -> np.ndarray:
        """Triangles of the posed mesh facing a camera looking along ``view_dir``."""
        n = np.asarray(triangle_normals(self.vertices, self.faces))
        return n @ np.asarray(view_dir, dtype=np.float64) < 0

    def add_marker(self, triangle: int, barycentric=None, view_dir=None) -> int:
        """Add a marker on ``triangle`` (centre unless ``barycentric``), its target at its
        current position; with ``view_dir``, only a triangle facing that camera."""
        with self._lock:
            t = int(triangle)
            if not 0 <= t < len(self.faces):
                raise FxspaceError(f"triangle {t} does not exist (0..{len(self.faces) - 1})")
            if t in self.triangles:
                raise FxspaceError(f"triangle {t} already holds a marker (one per triangle)")
            if view_dir is not None and not self.visible(view_dir)[t]:
                raise FxspaceError(f"triangle {t} faces away from the camera; pick a visible one")
            b = np.full(3, 1 / 3) if barycentric is None else np.asarray(barycentric, float)
            if b.shape != (3,) or np.any(b < -1e-9) or abs(b.sum() - 1) > 1e-6:
                raise FxspaceError("barycentric must be 3 non-negative numbers summing to 1")
            self.triangles.append(t)
            self.barycentric.append(b)
            self.targets = np.vstack([self.targets, self.marker_points()[-1:]])
            self._model = None
            self.message = f"marker {self.num_markers - 1} on triangle {t}"
            return self.num_markers - 1

    def pick(self, ray_origin, ray_direction) -> int | None:
        """Add a marker where the ray first hits a triangle facing it (Möller–Trumbore);
        returns the marker index, or None when the ray misses the mesh."""
        o = np.asarray(ray_origin, np.float64)
        d = np.asarray(ray_direction, np.float64)
        tri = self.vertices[self.faces]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        p = np.cross(d, e2)
        det = np.einsum("fc,fc->f", e1, p)
        facing = np.einsum("fc,c->f", np.cross(e1, e2), d) < 0
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - tri[:, 0]
        u = np.einsum("fc,fc->f", s, p) * inv
        q = np.cross(s, e1)
        v = np.einsum("c,fc->f", d, q) * inv
        t = np.einsum("fc,fc->f", e2, q) * inv
        hit = ok & facing & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        free = np.ones(len(self.faces), bool)
        free[self.triangles] = False
        hit &= free
        if not hit.any():
            self.message = "no free visible triangle under the cursor"
            return None
        f = int(np.flatnonzero(hit)[np.argmin(t[hit])])
        return self.add_marker(f, np.array([1 - u[f] - v[f], u[f], v[f]]))

    def remove_marker(self, index: int) -> None:
        with self._lock:
            if not 0 <= index < self.num_markers:
                raise FxspaceError(f"marker {index} does not exist ({self.num_markers} markers)")
            del self.triangles[index]
            del self.barycentric[index]
            self.constraints = {
                (i - (i > index)): kind for i, kind in self.constraints.items() if i != index
            }
            self.targets = np.delete(self.targets, index, axis=0)
            self._model = None
            self.message = f"removed marker {index}; {self.num_markers} left"

    # ------------------------------------------------------------------ solving
    def _ik(self):
        if self._model is None:
            self._model = ik_model(self.mesh, self.marker_set(), dtype=jnp.float32)
        return self._model

    def add_constraint(self, index: int, kind: str) -> None:
        """Constrain marker ``index``: ``"normal"`` (keep its surface normal as it is now,
        `fxspace.mesh.normal_constraint`), ``"floor"`` (keep it on the floor plane
        ``y = floor_height``, `fxspace.mesh.plane_contact`; its target no longer pulls) or
        ``"none"`` (remove the constraint); re-solves."""
        with self._lock:
            if not 0 <= index < self.num_markers:
                raise FxspaceError(f"marker {index} does not exist ({self.num_markers} markers)")
            if kind not in ("normal", "floor", "none"):
                raise FxspaceError(f"kind must be 'normal', 'floor' or 'none', got {kind!r}")
            if kind == "none":
                self.constraints.pop(index, None)
            else:
                self.constraints[index] = kind
            self._normals = self._current_normals()
            self.solve()
            self.message = f"marker {index}: constraint {kind}; " + self.message

    def _current_normals(self) -> np.ndarray:
        n = np.asarray(triangle_normals(self.vertices, self.faces))[np.asarray(self.triangles)]
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)

    def ik_constraints(self):
        """The `fxspace.mesh.IKConstraints` of the markers' constraints (None when there
        are none) and the target normals of the normal-constrained markers."""
        if not self.constraints:
            return None, None
        model = self._ik()
        normal = sorted(i for i, k in self.constraints.items() if k == "normal")
        floor = sorted(i for i, k in self.constraints.items() if k == "floor")
        w = np.ones(self.num_markers)
        w[floor] = 0.0
        nc = ct = tn = None
        if normal:
            nc = normal_constraint(
                self.mesh, self.marker_set(), self.constraint_weight["normal"], normal, jnp.float32
            )
            normals = self._normals
            if normals is None or len(normals) != self.num_markers:
                normals = self._current_normals()
            tn = jnp.asarray(normals[normal], jnp.float32)
        if floor:
            ct = plane_contact(
                model, floor, (0.0, 1.0, 0.0), self.floor_height, self.constraint_weight["floor"]
            )
        return ik_constraints(model, marker_weights=w, normal=nc, contact=ct), tn

    def solve(self):
        """One warm-started IK solve towards the current targets (and the markers'
        constraints); updates the pose."""
        with self._lock:
            if not self.num_markers:
                self.message = "add a marker first"
                return None
            t0 = time.perf_counter()
            cons, tn = self.ik_constraints()
            res = solve_ik(
                self._ik(),
                jnp.asarray(self.targets, jnp.float32),
                self.pose,
                constraints=cons,
                target_normals=tn,
            )
            if res.result not in (RESULTS.nonfinite_input, RESULTS.nonfinite_output):
                self.pose = res.pose
                self.vertices = np.asarray(self._posed(self.pose))
            self.last_result = res
            ms = 1e3 * (time.perf_counter() - t0)
            self.message = (
                f"solved in {int(res.num_steps)} steps, {ms:.1f} ms, marker RMS "
                f"{float(res.residual):.3g}"
            )
            return res

    def move_target(self, index: int, position) -> None:
        """Set marker ``index``'s target and re-solve (warm start)."""
        with self._lock:
            if not 0 <= index < self.num_markers:
                raise FxspaceError(f"marker {index} does not exist ({self.num_markers} markers)")
            pos = np.asarray(position, np.float64).reshape(3)
            if not np.all(np.isfinite(pos)):
                raise FxspaceError(f"target must be 3 finite numbers, got {position!r}")
            self.targets[index] = pos
            self.solve()

    # ------------------------------------------------------------------ animation
    def set_time(self, t: float) -> None:
        """Targets from the mesh's animation at time ``t`` (the markers on the animated
        surface), solve, and record the pose (tracking)."""
        if self.animation is None:
            self.message = "this mesh has no animation"
            return
        with self._lock:
            self.time = float(t)
            if not self.num_markers:
                self.vertices = animation_vertices(self.mesh, self.animation, [self.time])[0]
                return
            v = animation_vertices(self.mesh, self.animation, [self.time])[0]
            self.targets = np.asarray(marker_positions(v, self.faces, self.marker_set()))
            self.solve()
            self.recorded.append(self.pose)

    def step(self) -> float:
        """Advance the animation by one frame (wrapping) and track it."""
        t0, t1 = self.mesh.animation_range(self.animation)
        t = self.time + 1.0 / self.fps
        self.set_time(t0 if t > t1 else t)
        return self.time

    def _frames(self) -> tuple[np.ndarray, np.ndarray]:
        """The recorded frames (or the current pose): angles (T, J, 3), translation (T, 3)."""
        poses = self.recorded or [self.pose]
        ang = np.stack([np.asarray(p.angles) for p in poses])
        return ang, np.stack([np.asarray(p.translation) for p in poses])

    def export_bvh(self, path) -> Path:
        """Write the recorded frames (or the current pose) as BVH."""
        from fxspace.io import write_ik_bvh

        ang, tr = self._frames()
        out = write_ik_bvh(path, self.mesh, ang, tr, rate=self.fps)
        self.message = f"wrote {len(ang)} frame(s) to {out}"
        return out

    def export_gltf(self, path) -> Path:
        """Write the mesh and the recorded frames (or the current pose) as glTF."""
        from fxspace.io import write_ik_gltf

        ang, tr = self._frames()
        out = write_ik_gltf(path, self.mesh, ang, tr, rate=self.fps)
        self.message = f"wrote {len(ang)} frame(s) to {out}"
        return out

    def status(self) -> str:
        cons = ", ".join(f"{i}: {k}" for i, k in sorted(self.constraints.items()))
        return (
            f"**Markers: {self.num_markers}**"
            + (f"  \nConstraints: {cons}" if cons else "")
            + f"  \n{'Playing' if self.playing else 'Paused'}"
            f" t = {self.time:.2f} s  \n{self.message}"
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
        self.gui_status = gui.add_markdown(ctl.status())
        self.tri_text = gui.add_text("Triangle", initial_value="0")
        self.add_btn = gui.add_button("Add marker")
        self.idx_text = gui.add_text("Marker", initial_value="0")
        self.tgt_text = gui.add_text("Target x y z", initial_value="")
        self.move_btn = gui.add_button("Move target")
        self.rm_btn = gui.add_button("Remove marker")
        self.kind = gui.add_dropdown("Constraint", ("normal", "floor", "none"))
        self.cons_btn = gui.add_button("Constrain marker")
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

    def _redraw(self, gizmos: bool = True) -> None:
        self.draw_mesh()
        self.draw_markers(gizmos)
        self.gui_status.content = self.ctl.status()

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

    def _toggle_play(self) -> None:
        self.ctl.playing = not self.ctl.playing
        if self.ctl.playing:
            self.ctl.recorded = []

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
        self.play_btn.on_click(lambda _e: self.guarded(self._toggle_play))
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
):
    """Serve the IK studio for ``target`` (see `load_ik_mesh`); ``port=0`` picks a free
    port (``server.get_port()``), or pass `options`, a `ServeOptions`, which wins over
    the keywords. With ``block=False`` returns ``(server, controller)`` at once (stop with
    ``server.stop()``; the page's `IKView` is ``server.fxspace_view``). *Export glTF*
    writes `gltf_path` (default: `export_path` with the suffix ``.glb``)."""
    o = options or ServeOptions(port, host, 30.0, block, environment_map)
    mesh, anim = load_ik_mesh(target)
    ctl = IKController(mesh, anim, fps=o.fps)
    server = new_server(o.port, o.host, o.environment_map)
    if gltf_path is None:
        bvh = Path(export_path)
        gltf_path = bvh.with_name(bvh.name.removesuffix(".gz").removesuffix(".bvh") + ".glb")
    view = IKView(server, ctl, export_path, gltf_path)
    server.fxspace_view = view

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
