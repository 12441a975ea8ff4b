"""The mesh-IK studio's state and actions (Park, Kang & Kwon's interactive system),
independent of any UI: `IKController` (testable without a browser) and `load_ik_mesh`.
The page (`IKView`, `serve_ik`) is in ``_ik``."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.mesh import (
    BFGS,
    LevenbergMarquardt,
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

__all__ = ["IKController", "load_ik_mesh", "IK_SOLVERS"]

#: The solvers the studio offers (name → what it uses). Levenberg–Marquardt, the default,
#: steps on the analytic Jacobian of the marker residuals (not eq. 13); the paper's
#: gradient path is BFGS driven by eq. (13), its naive form eq. (9) beside it.
IK_SOLVERS = {
    "lm": "Levenberg–Marquardt, analytic Jacobian (default)",
    "bfgs_factored": "BFGS on the factored gradient, eq. (13) (the paper's gradient)",
    "bfgs_naive": "BFGS on the naive gradient, eq. (9)",
}


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
        self._exported: set[Path] = set()  # the files this app's exports wrote
        self.constraints: dict[int, str] = {}  # marker index → "normal" | "floor"
        self.constraint_weight = {"normal": 0.1, "floor": 100.0}
        self._model = None
        self._posed = jax.jit(lambda p: pose_vertices(mesh, p))
        self.vertices = np.asarray(self._posed(self.pose))
        self.floor_height = float(self.vertices[:, 1].min())  # the rest pose's lowest point
        self._normals = None
        self._lock = threading.RLock()
        self.solver = "lm"  # see IK_SOLVERS
        self.take = None  # a BVH take retargeted onto the mesh (`load_take`)
        self.take_name = ""
        self.take_frame = 0

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

    def set_solver(self, name: str) -> None:
        """Choose the solver (`IK_SOLVERS`: ``"lm"``, the default; ``"bfgs_factored"``,
        the paper's gradient path; ``"bfgs_naive"``) for the next solves."""
        if name not in IK_SOLVERS:
            raise FxspaceError(f"solver must be one of {list(IK_SOLVERS)}, got {name!r}")
        with self._lock:
            self.solver = name
            self.message = f"solver: {IK_SOLVERS[name]}"

    def _solver(self):
        if self.solver == "lm":
            return LevenbergMarquardt()
        return BFGS(gradient=self.solver.removeprefix("bfgs_"))

    def solve(self):
        """One warm-started IK solve towards the current targets (and the markers'
        constraints) with the chosen solver (`set_solver`); updates the pose."""
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
                solver=self._solver(),
            )
            if res.result not in (RESULTS.nonfinite_input, RESULTS.nonfinite_output):
                self.pose = res.pose
                self.vertices = np.asarray(self._posed(self.pose))
            self.last_result = res
            ms = 1e3 * (time.perf_counter() - t0)
            self.message = (
                f"{self.solver}: solved in {int(res.num_steps)} steps, {ms:.1f} ms, marker RMS "
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

    # ------------------------------------------------------------------ a BVH take
    def load_take(self, path, joint_map=None, max_frames: int = 600) -> int:
        """Read a BVH take and retarget it onto the mesh (`fxspace.mesh.retarget`: the
        source scaled to the character, feet planted where the source's are; `joint_map`
        defaults to `fxspace.motion.joint_map_for`, roles by joint name), show its first
        frame; *Play / Pause* then plays it (recorded: the exports write it). Takes
        longer than `max_frames` are cut there (said). Returns the number of frames."""
        from fxspace.io import read_bvh
        from fxspace.mesh import retarget
        from fxspace.motion import joint_map_for

        p = Path(str(path).strip()).expanduser()
        if not str(path).strip() or not p.is_file():
            raise FxspaceError(f"BVH take {str(path)!r}: no such file; type the path of a .bvh")
        take = read_bvh(p, units="auto")  # Bandai: cm, CMU conversions: inches…
        cut = take.num_frames > max_frames
        if cut:
            take = take.frames(slice(0, max_frames))
        res = retarget(take, self.mesh, joint_map_for if joint_map is None else joint_map,
                       baseline=False)  # fmt: skip
        with self._lock:
            self.take, self.take_name, self.playing = res, p.name, False
            self.recorded = []
            self._show_take_frame(0)
            sm = res.summary()
            self.message = (
                f"take {p.name}: {len(res.joint_error)} frames{' (cut)' if cut else ''} "
                f"retargeted, {len(res.correspondences)} joints paired, joint error "
                f"{sm['joint_error_median']:.3f} heights ({res.result!r})"
            )
        return len(res.joint_error)

    def _show_take_frame(self, f: int) -> None:
        r = self.take
        self.take_frame = int(f)
        self.pose = Pose(jnp.asarray(r.pose.angles[f], jnp.float32),
                         jnp.asarray(r.pose.translation[f], jnp.float32))  # fmt: skip
        self.vertices = np.asarray(self._posed(self.pose))
        self.time = f / r.rate

    def take_overlay(self):
        """The take's frame as drawn: ``(source joints (M, 3), character joints (M, 3),
        contacts (M,) bool)`` (the scaled source's joints, the character's corresponded
        joints, the feet in contact), or ``None`` without a take."""
        r = self.take
        if r is None:
            return None
        f = self.take_frame
        return (np.asarray(r.targets[f]), np.asarray(r.joints[f]),
                np.asarray(r.contacts[f], bool))  # fmt: skip

    def step(self) -> float:
        """Advance the animation (or the loaded take) by one frame (wrapping) and track
        it."""
        if self.take is not None:
            with self._lock:
                self._show_take_frame((self.take_frame + 1) % len(self.take.joint_error))
                self.recorded.append(self.pose)
            return self.time
        t0, t1 = self.mesh.animation_range(self.animation)
        t = self.time + 1.0 / self.fps
        self.set_time(t0 if t > t1 else t)
        return self.time

    def _frames(self) -> tuple[np.ndarray, np.ndarray]:
        """The recorded frames (or the current pose): angles (T, J, 3), translation (T, 3)."""
        poses = self.recorded or [self.pose]
        ang = np.stack([np.asarray(p.angles) for p in poses])
        return ang, np.stack([np.asarray(p.translation) for p in poses])

    def _own_path(self, path) -> tuple[Path, str]:
        """Where an export goes: ``path`` when it is free or this app wrote it (this
        session), else the first free ``NAME-2.EXT``, ``NAME-3.EXT``… beside it — a file
        the user has there (or a link) is never overwritten. Returns (path, a note)."""
        import os

        p = Path(path)
        if not os.path.lexists(p) or Path(os.path.abspath(p)) in self._exported:
            return p, ""
        stem, dot, ext = p.name.partition(".")
        for n in range(2, 10_000):
            q = p.with_name(f"{stem}-{n}{dot}{ext}")
            if not os.path.lexists(q) or Path(os.path.abspath(q)) in self._exported:
                return q, f" ({p.name} exists and this app did not write it: kept)"
        raise FxspaceError(f"{p}: no free name beside it; move the old exports away")

    def _exported_to(self, out: Path) -> None:
        import os

        self._exported.add(Path(os.path.abspath(out)))

    def export_bvh(self, path) -> Path:
        """Write the recorded frames (or the current pose) as BVH (beside ``path`` when a
        file this app did not write is there, see `_own_path`)."""
        from fxspace.io import write_ik_bvh

        ang, tr = self._frames()
        path, note = self._own_path(path)
        out = write_ik_bvh(path, self.mesh, ang, tr, rate=self.fps)
        self._exported_to(out)
        self.message = f"wrote {len(ang)} frame(s) to {out}{note}"
        return out

    def export_gltf(self, path) -> Path:
        """Write the mesh and the recorded frames (or the current pose) as glTF (beside
        ``path`` when a file this app did not write is there, see `_own_path`)."""
        from fxspace.io import write_ik_gltf

        ang, tr = self._frames()
        path, note = self._own_path(path)
        out = write_ik_gltf(path, self.mesh, ang, tr, rate=self.fps)
        self._exported_to(out)
        self.message = f"wrote {len(ang)} frame(s) to {out}{note}"
        return out

    def toggle_play(self) -> bool:
        """Start or stop playing the mesh's animation (tracked with the current markers);
        starting clears the recorded frames. Returns whether it now plays."""
        with self._lock:
            if self.animation is None and self.take is None:
                self.message = "this mesh has no animation (load a BVH take)"
                return False
            self.playing = not self.playing
            if self.playing:
                self.recorded = []
            return self.playing

    def status(self) -> dict:
        """What the status panel shows, as data (`IKView` renders it): ``markers`` (the
        count), ``constraints`` (marker → kind), ``playing``, ``time`` (s), ``take`` (the
        loaded BVH take's file name, or None), the last
        solve's ``num_steps`` and ``residual`` (None before one) and the last
        ``message``."""
        r = self.last_result
        return {
            "markers": self.num_markers,
            "constraints": dict(sorted(self.constraints.items())),
            "playing": bool(self.playing),
            "time": float(self.time),
            "take": self.take_name if self.take is not None else None,
            "solver": self.solver,
            "num_steps": None if r is None else int(r.num_steps),
            "residual": None if r is None else float(r.residual),
            "message": self.message,
        }
