"""Live retargeting (`fxspace.mesh.live_retarget`): one frame of a live source's joints
at a time onto a skinned character by the mesh IK, warm-started from the previous frame.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from fxspace.mesh._ik_constraints import IKConstraints, joint_limits, joint_prior
from fxspace.mesh._ik_solvers import LevenbergMarquardt, _pick_solver, _solve
from fxspace.mesh._retarget_inputs import RetargetError, _pairs
from fxspace.mesh._retarget_kinematics import _char_rest, _joint_model, _path_length, _source_fk
from fxspace.mesh._skinning import Pose, _pose_vertices, skin_tables

__all__ = ["LiveRetarget", "live_retarget"]


class LiveRetarget:
    """Frame-by-frame retargeting for a live source (the walker): `step` takes the
    source's world joint positions of one frame and returns the character's `Pose` and
    skinned vertices, warm-started from the previous frame (no contacts: the live source
    has no future to plan a plant on). Build with `live_retarget`."""

    def __init__(self, skeleton, mesh, joint_map=None, *, solver=None, limit=0.8 * np.pi,
                 prior_weight: float = 1e-4):  # fmt: skip
        if not hasattr(mesh, "joint_names") or not hasattr(mesh, "inverse_bind"):
            raise RetargetError(f"mesh must be a SkinnedMesh, got {type(mesh).__name__}")
        for f in ("names", "parents", "offsets"):
            if not hasattr(skeleton, f):
                raise RetargetError(
                    f"skeleton must have names, parents and offsets (a Motion), lacking {f}"
                )
        names = tuple(str(n) for n in skeleton.names)
        parents = np.asarray(skeleton.parents, np.int64)
        off = np.asarray(skeleton.offsets, np.float64)
        pairs, _ = _pairs(joint_map, names, tuple(mesh.joint_names))
        self.mesh, self.pairs = mesh, tuple(pairs)
        self.si = np.array([names.index(s) for s, _ in pairs])
        self.ci = np.array([mesh.joint_names.index(c) for _, c in pairs])
        g_rest, _ = _char_rest(mesh)
        c_rest = g_rest[self.ci, :3, 3]
        ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, len(names), 1))
        x_rest = _source_fk(parents, off, np.zeros((1, 3)), ident)[0][0]
        hi, lo = int(np.argmax(c_rest[:, 1])), int(np.argmin(c_rest[:, 1]))
        cpar = np.asarray(mesh.parents)
        span_c = _path_length(cpar, g_rest[:, :3, 3], self.ci[hi], self.ci[lo])
        span_s = _path_length(parents, x_rest, self.si[hi], self.si[lo])
        if not span_s > 0 or not span_c > 0:
            raise RetargetError("the corresponded joints span no height")
        self.scale = float(span_c / span_s)
        verts = np.asarray(mesh.vertices, np.float64)
        self.height = float(np.ptp(verts[:, 1]))
        self._lift = float(c_rest[:, 1].min())  # the lowest joint's rest height
        self._offset: float | None = None
        self.model = _joint_model(mesh, self.ci, self.height)
        dt = self.model.local_rest.dtype
        self.cons = IKConstraints(
            limits=joint_limits(self.model, float(limit), 1.0),
            prior=joint_prior(self.model, float(prior_weight), "rest")
            if prior_weight > 0
            else None,
        )
        lm = LevenbergMarquardt(rtol=1e-3, xtol=1e-3, max_steps=20)
        self.solver = _pick_solver(solver or lm)
        self.pose = Pose(jnp.zeros((mesh.num_joints, 3), dt), jnp.zeros((3,), dt))
        self._tables = skin_tables(mesh)
        self._skin = _pose_vertices
        self._dtype = dt

    def targets(self, x: np.ndarray) -> np.ndarray:
        """The character-space targets of one frame's source joints ``(J_src, 3)``."""
        t = self.scale * np.asarray(x, np.float64)[self.si]
        if self._offset is None:  # the first frame sets the floor: lowest joint at rest height
            self._offset = self._lift - float(t[:, 1].min())
        t[:, 1] += self._offset
        return t

    def step(self, x) -> tuple[Pose, np.ndarray]:
        """Solve one frame (warm from the last) → ``(pose, vertices (V, 3))``."""
        t = jnp.asarray(self.targets(x), self._dtype)
        res = _solve(self.model, self.cons, t, self.pose, None, self.solver)
        if bool(jnp.all(jnp.isfinite(res.pose.angles))):
            self.pose = res.pose
        v = self._skin(self.mesh, self._tables, self.pose.angles, self.pose.translation)
        return self.pose, np.asarray(v)


def live_retarget(skeleton, mesh, joint_map=None, **kwargs) -> LiveRetarget:
    """A `LiveRetarget` of ``skeleton`` (a Motion's ``names``/``parents``/``offsets``) onto
    ``mesh``: ``lr.step(world_joint_positions)`` → ``(Pose, skinned vertices)`` per frame.
    ``joint_map`` as in `retarget`; keywords ``solver``, ``limit``, ``prior_weight``."""
    return LiveRetarget(skeleton, mesh, joint_map, **kwargs)
