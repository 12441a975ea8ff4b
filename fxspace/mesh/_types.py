"""Skinned-mesh data types: `SkinnedMesh`, `Animation`, `LocalPose`.

Read from glTF by `fxspace.io.read_gltf`; posed by linear blend skinning in
`fxspace.mesh` (`fxspace.mesh.animation_vertices`, `fxspace.mesh.pose_vertices`). They
live here (not in the reader) so that skinning and IK import them without importing any
reader, and they hold data only: no method calls an algorithm module.

`SkinnedMesh` is a registered pytree: its arrays are the leaves; the name, the joint
names and nodes, the parent table (the skeleton's topology, static under ``jit``) and
the animations are static auxiliary data.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.rotations import quat_normalize, quat_slerp

__all__ = ["SkinnedMesh", "Animation", "AnimationChannel", "LocalPose", "sample_channel"]


class AnimationChannel(NamedTuple):
    """One animated property of one joint (times in seconds, values per key)."""

    joint: int  # index into SkinnedMesh's joint order
    path: str  # "translation" | "rotation" | "scale"
    times: np.ndarray  # (n,) increasing
    values: np.ndarray  # (n, c) or, for CUBICSPLINE, (n, 3, c): in-tangent, value, out-tangent
    interpolation: str  # "LINEAR" | "STEP" | "CUBICSPLINE"


class Animation(NamedTuple):
    name: str
    channels: tuple[AnimationChannel, ...]

    @property
    def start(self) -> float:
        return float(min(c.times[0] for c in self.channels)) if self.channels else 0.0

    @property
    def end(self) -> float:
        return float(max(c.times[-1] for c in self.channels)) if self.channels else 0.0


class LocalPose(NamedTuple):
    """Local joint transforms ``(..., J, ·)``: translation, quaternion (x, y, z, w), scale."""

    translations: np.ndarray  # (..., J, 3)
    rotations: np.ndarray  # (..., J, 4) unit quaternions, glTF order (x, y, z, w)
    scales: np.ndarray  # (..., J, 3)


@dataclasses.dataclass(frozen=True, eq=False)
class SkinnedMesh:
    """A skinned triangle mesh with its skeleton and animations (float64 numpy arrays).

    Joints are ordered so that ``parents[j] < j`` (parents first); ``joint_nodes`` gives
    each joint's glTF node index. ``base_transforms[j]`` is the fixed global transform of
    the (non-joint) nodes above a root joint (identity for the other joints).
    ``skin_joints``/``skin_weights`` hold ``I = 4 × (number of JOINTS_n sets)``
    influences per vertex, weights normalised to sum to 1.
    """

    name: str
    vertices: np.ndarray  # (V, 3) bind pose
    faces: np.ndarray  # (F, 3) int32, counter-clockwise = front
    joint_names: tuple[str, ...]
    joint_nodes: tuple[int, ...]
    parents: np.ndarray  # (J,) int32, -1 for a root
    rest_translations: np.ndarray  # (J, 3)
    rest_rotations: np.ndarray  # (J, 4) quaternions (x, y, z, w)
    rest_scales: np.ndarray  # (J, 3)
    base_transforms: np.ndarray  # (J, 4, 4)
    inverse_bind: np.ndarray  # (J, 4, 4)
    skin_joints: np.ndarray  # (V, I) int32
    skin_weights: np.ndarray  # (V, I)
    animations: dict[str, Animation]

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def animation_names(self) -> tuple[str, ...]:
        return tuple(self.animations)

    def rest_pose(self) -> LocalPose:
        """The joints' rest (node) transforms as a `LocalPose` of shape (J, ·)."""
        return LocalPose(self.rest_translations, self.rest_rotations, self.rest_scales)

    def _animation(self, name: str | int) -> Animation:
        if isinstance(name, int) and not isinstance(name, bool):
            names = self.animation_names
            if not 0 <= name < len(names):
                raise FxspaceError(f"animation index {name} out of range; {self.name} has {names}")
            name = names[name]
        if name not in self.animations:
            raise FxspaceError(
                f"animation {name!r} not in {self.name}; choose one of {list(self.animations)}"
            )
        return self.animations[name]

    def animation_range(self, name: str | int) -> tuple[float, float]:
        """(start, end) time in seconds of animation ``name``."""
        a = self._animation(name)
        return a.start, a.end

    def sample_animation(self, name: str | int, times: np.ndarray | float) -> LocalPose:
        """Local joint transforms of animation ``name`` at ``times`` (seconds, clamped to range).

        Joints without a channel keep their rest transform. ``LINEAR`` rotations use
        spherical linear interpolation (shortest arc), ``CUBICSPLINE`` the Hermite form
        of the glTF specification (Appendix C), ``STEP`` the previous key.

        **Returns:** a `LocalPose` with leading shape ``(T, J)`` (``(J,)`` for a scalar).
        """
        anim = self._animation(name)
        t = np.asarray(times, dtype=np.float64)
        scalar = t.ndim == 0
        t = np.atleast_1d(t)
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise FxspaceError(f"times must be a finite scalar or 1-D array, got shape {t.shape}")
        n = t.shape[0]
        out = {
            "translation": np.broadcast_to(self.rest_translations, (n, self.num_joints, 3)).copy(),
            "rotation": np.broadcast_to(self.rest_rotations, (n, self.num_joints, 4)).copy(),
            "scale": np.broadcast_to(self.rest_scales, (n, self.num_joints, 3)).copy(),
        }
        for ch in anim.channels:
            out[ch.path][:, ch.joint] = sample_channel(ch, t)
        pose = LocalPose(out["translation"], out["rotation"], out["scale"])
        if scalar:
            pose = LocalPose(*(a[0] for a in pose))
        return pose


_ARRAY_FIELDS = (
    "vertices",
    "faces",
    "rest_translations",
    "rest_rotations",
    "rest_scales",
    "base_transforms",
    "inverse_bind",
    "skin_joints",
    "skin_weights",
)


class _Static:
    """Static pytree data compared by identity (the animations hold arrays, which have no
    usable ``==``): a mesh's treedef equals another's only for the same animations."""

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Static) and other.value is self.value

    def __hash__(self) -> int:
        return id(self.value)


def _flatten_mesh(m: SkinnedMesh):
    aux = (
        m.name,
        m.joint_names,
        m.joint_nodes,
        tuple(int(p) for p in np.asarray(m.parents)),
        _Static(m.animations),
    )
    return tuple(getattr(m, f) for f in _ARRAY_FIELDS), aux


def _unflatten_mesh(aux, children) -> SkinnedMesh:
    name, joint_names, joint_nodes, parents, anims = aux
    arrays = dict(zip(_ARRAY_FIELDS, children, strict=True))
    return SkinnedMesh(
        name=name,
        joint_names=joint_names,
        joint_nodes=joint_nodes,
        parents=np.asarray(parents, dtype=np.int32),
        animations=anims.value,
        **arrays,
    )


jax.tree_util.register_pytree_node(SkinnedMesh, _flatten_mesh, _unflatten_mesh)


# ----------------------------------------------------------------------------- sampling


def sample_channel(ch: AnimationChannel, t: np.ndarray) -> np.ndarray:
    """Value of one channel at times ``t`` (clamped to the keyframe range), shape (n, c)."""
    keys = ch.times
    tc = np.clip(t, keys[0], keys[-1])
    if keys.shape[0] == 1:
        v = ch.values[0, 1] if ch.interpolation == "CUBICSPLINE" else ch.values[0]
        return np.broadcast_to(v, (t.shape[0], v.shape[-1])).copy()
    i = np.clip(np.searchsorted(keys, tc, side="right") - 1, 0, keys.shape[0] - 2)
    t0, t1 = keys[i], keys[i + 1]
    dt = t1 - t0
    u = np.where(dt > 0, (tc - t0) / np.where(dt > 0, dt, 1.0), 0.0)
    if ch.interpolation == "STEP":
        v = np.where((u >= 1.0)[:, None], ch.values[i + 1], ch.values[i])
    elif ch.interpolation == "CUBICSPLINE":
        p0, m0 = ch.values[i, 1], ch.values[i, 2] * dt[:, None]
        p1, m1 = ch.values[i + 1, 1], ch.values[i + 1, 0] * dt[:, None]
        u_ = u[:, None]
        u2, u3 = u_**2, u_**3
        v = (
            (2 * u3 - 3 * u2 + 1) * p0
            + (u3 - 2 * u2 + u_) * m0
            + (-2 * u3 + 3 * u2) * p1
            + (u3 - u2) * m1
        )
        if ch.path == "rotation":
            v = quat_normalize(v)
    elif ch.path == "rotation":
        v = quat_slerp(ch.values[i], ch.values[i + 1], u)
    else:
        u_ = u[:, None]
        v = (1.0 - u_) * ch.values[i] + u_ * ch.values[i + 1]
    return v
