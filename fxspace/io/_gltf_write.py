"""Skinned meshes, their poses and IK poses → glTF 2.0 (``.glb``, or ``.gltf`` + data URI).

The file holds what `fxspace.io.read_gltf` reads (glTF 2.0 §3.7.3 skins, §3.11
animations):

- one triangle primitive: bind-pose ``POSITION`` (float32), ``indices`` (uint32) and the
  skin influences as ``JOINTS_n``/``WEIGHTS_n`` sets of 4 (a joint at most once per
  vertex, weights renormalised to sum 1, heaviest first);
- one skin whose joints are nodes ``0 … J−1`` in the mesh's joint order, each with its
  rest ``translation``/``rotation`` (x, y, z, w)/``scale``, and the inverse bind matrices;
- above each root joint whose ``base_transforms`` is not the identity, a non-joint node
  holding that fixed transform as a ``matrix`` (so the re-read ``base_transforms`` match);
- with ``poses`` (a `fxspace.mesh.LocalPose` ``(T, J, ·)``): one animation with
  ``LINEAR`` translation / rotation / scale channels per joint keyed at ``times``
  (quaternion signs made continuous over time, so interpolation takes the short arc).

IK poses (`fxspace.Pose`: per-joint XYZ Euler angles ``θ_j`` after the rest
rotation, plus a world translation ``τ``) become local transforms with
`ik_poses_to_local`: ``R_j = R_rest,j · R_x R_y R_z(θ_j)``, rest translations and
scales, and ``τ`` moved into each root's translation as ``t_root + B⁻¹ τ`` (``B`` the
linear part of the root's base transform), which moves every joint's global transform by
``τ``: with weights summing to one, the skinned vertices move by ``τ`` exactly as
`fxspace.pose_vertices` does.

Example:

```python
mesh = fx.io.read_gltf("CesiumMan.glb")
t = np.linspace(0.0, 2.0, 49)
fx.io.write_gltf("copy.glb", mesh, mesh.sample_animation("Anim_0", t), times=t)
fx.io.write_ik_gltf("ik.glb", mesh, res.pose.angles, res.pose.translation, rate=30.0)
```
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.io._gltf_checks import _check_ik, _check_mesh, _check_poses, _check_times
from fxspace.io._ik_bvh import retargeted_pose
from fxspace.mesh import LocalPose
from fxspace.rotations import euler_to_matrix, matrix_to_quat, quat_normalize, quat_to_matrix

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh import SkinnedMesh

__all__ = ["ik_poses_to_local", "write_gltf", "write_ik_gltf", "write_gltf_animation"]

_FLOAT, _U16, _U32 = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


# ----------------------------------------------------------------------------- IK poses


@checked
def ik_poses_to_local(mesh: SkinnedMesh, angles, translation) -> LocalPose:
    """Local joint transforms of IK poses (`fxspace.Pose` fields) of ``mesh``.

    Joint ``j`` gets rotation ``R_rest,j · R_x R_y R_z(θ_j)`` (as an ``(x, y, z, w)``
    quaternion), its rest scale, and its rest translation; a root ``r`` also gets the world
    translation ``τ`` as ``t_r + B_r⁻¹ τ`` (``B_r`` the linear part of
    ``mesh.base_transforms[r]``), so ``G_j`` moves by ``τ`` for every joint and
    ``fx.skin_local_pose(mesh, ik_poses_to_local(mesh, a, τ))`` equals
    ``fx.pose_vertices(mesh, fx.Pose(a, τ))`` (weights summing to one).

    **Arguments:** `mesh`; `angles` ``(J, 3)`` or ``(T, J, 3)`` radians; `translation`
    ``(3,)`` or ``(T, 3)``.

    **Returns:** a `fxspace.mesh.LocalPose` with leading shape ``(J,)`` or
    ``(T, J)`` (float64), the input of `write_gltf` and `fxspace.skin_local_pose`.
    """
    ang, tr, single = _check_ik(mesh, angles, translation)
    nt, nj = ang.shape[:2]
    q_rest = quat_normalize(np.asarray(mesh.rest_rotations, np.float64))
    r = np.asarray(quat_to_matrix(q_rest, order="xyzw"))[None] @ np.asarray(
        euler_to_matrix(ang, "XYZ")
    )
    q = np.asarray(matrix_to_quat(r, order="xyzw"))
    t = np.broadcast_to(np.asarray(mesh.rest_translations, np.float64), (nt, nj, 3)).copy()
    s = np.broadcast_to(np.asarray(mesh.rest_scales, np.float64), (nt, nj, 3)).copy()
    for root in np.flatnonzero(np.asarray(mesh.parents) < 0):
        lin = np.asarray(mesh.base_transforms[root], np.float64)[:3, :3]
        if abs(np.linalg.det(lin)) < 1e-12 * max(np.abs(lin).max(), 1e-300) ** 3:
            raise FxspaceError(
                f"mesh.base_transforms[{root}] is singular: the world translation cannot be "
                "expressed in the root's frame (fix the transforms above the skeleton)"
            )
        t[:, root] += np.linalg.solve(lin, tr.T).T
    pose = LocalPose(t, q, s)
    return LocalPose(*(a[0] for a in pose)) if single else pose


# ----------------------------------------------------------------------------- writing


class _Buffer:
    """One binary buffer with its buffer views and accessors (4-byte aligned)."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, arr: np.ndarray, ctype: int, kind: str, target=None, minmax=False) -> int:
        arr = np.ascontiguousarray(arr)
        data = arr.astype(arr.dtype.newbyteorder("<")).tobytes()
        view = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.chunks.append(data + b"\0" * (-len(data) % 4))
        self.size += len(self.chunks[-1])
        self.views.append(view)
        acc = {
            "bufferView": len(self.views) - 1,
            "componentType": ctype,
            "count": int(arr.shape[0]),
            "type": kind,
        }
        if minmax:
            flat = arr.reshape(arr.shape[0], -1).astype(np.float64)
            acc["min"], acc["max"] = flat.min(0).tolist(), flat.max(0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _influences(joints: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skin influences as glTF wants them: a joint at most once per vertex (repeats
    merged), weights summing to 1, the heaviest first, unused slots ``(joint 0, 0.0)``,
    and no more columns than the most influences any vertex has."""
    w = weights / weights.sum(axis=1, keepdims=True)
    j = joints.astype(np.int64)
    for a in range(w.shape[1]):
        for b in range(a + 1, w.shape[1]):
            same = (j[:, a] == j[:, b]) & (w[:, b] > 0)
            w[same, a] += w[same, b]
            w[same, b] = 0.0
    order = np.argsort(-w, axis=1, kind="stable")
    w = np.take_along_axis(w, order, axis=1)
    j = np.where(w > 0, np.take_along_axis(j, order, axis=1), 0)
    keep = max(int((w > 0).sum(axis=1).max()), 1)
    return w[:, :keep], j[:, :keep]


def _continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternion signs ``(T, J, 4)`` so consecutive keys have a non-negative dot."""
    if q.shape[0] < 2:
        return q
    d = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0, -1.0, 1.0)
    sign = np.concatenate([np.ones((1, q.shape[1])), np.cumprod(d, axis=0)])
    return q * sign[..., None]


@checked
def write_gltf(
    path: str | Path,
    mesh: SkinnedMesh,
    poses: LocalPose | None = None,
    times=None,
    rate: float = 30.0,
    animation: str = "fxspace",
) -> Path:
    """Write ``mesh`` (and, optionally, an animation of local poses) as glTF 2.0.

    **Arguments:**

    - `path`: ``.glb`` (binary) or ``.gltf`` (JSON with the buffer as a base64 data URI).
    - `mesh`: the `fxspace.mesh.SkinnedMesh` (bind pose, skin, skeleton).
    - `poses`: local joint transforms with leading shape ``(T, J)`` (or ``(J,)``), as
      `SkinnedMesh.sample_animation` or `ik_poses_to_local` return; ``None``
      writes the mesh without animations.
    - `times`: ``(T,)`` key times in seconds, ``≥ 0`` and strictly increasing (default
      ``arange(T) / rate``).
    - `rate`: frames per second when `times` is ``None``.
    - `animation`: the animation's name.

    **Returns:** the path written (atomically: a temporary file, then a rename).
    """
    from fxspace.runs import write_bytes_atomic

    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".glb", ".gltf"):
        raise FxspaceError(
            f"path must end in .glb (binary glTF) or .gltf (JSON, embedded buffer), got {p.name!r}"
        )
    m = _check_mesh(mesh)
    nj = mesh.num_joints
    if nj > 65535:
        raise FxspaceError(f"mesh has {nj} joints; JOINTS_n (uint16) hold at most 65535")
    if poses is None and times is not None:
        raise FxspaceError("times was given without poses; pass poses (T, J, ·) to animate")
    if poses is not None:
        pt, pq, ps = _check_poses(poses, nj)
        keys = _check_times(times, rate, pt.shape[0])
        if not isinstance(animation, str) or not animation:
            raise FxspaceError(f"animation must be a non-empty name, got {animation!r}")

    buf = _Buffer()
    v32 = m["vertices"].astype(np.float32)
    attributes = {"POSITION": buf.add(v32, _FLOAT, "VEC3", _ARRAY_BUFFER, minmax=True)}
    faces = buf.add(m["faces"].reshape(-1).astype(np.uint32), _U32, "SCALAR", _ELEMENT_ARRAY_BUFFER)
    w, sj = _influences(m["skin_joints"], m["skin_weights"])
    pad = -w.shape[1] % 4
    w = np.pad(w, ((0, 0), (0, pad))).astype(np.float32)
    sj = np.pad(sj, ((0, 0), (0, pad))).astype(np.uint16)
    for k in range(w.shape[1] // 4):
        cols = slice(4 * k, 4 * k + 4)
        attributes[f"JOINTS_{k}"] = buf.add(sj[:, cols], _U16, "VEC4", _ARRAY_BUFFER)
        attributes[f"WEIGHTS_{k}"] = buf.add(w[:, cols], _FLOAT, "VEC4", _ARRAY_BUFFER)
    ibm = buf.add(
        m["inverse_bind"].transpose(0, 2, 1).reshape(nj, 16).astype(np.float32), _FLOAT, "MAT4"
    )

    nodes, scene = _nodes(mesh, m)
    gltf: dict = {
        "asset": {"version": "2.0", "generator": "fxspace"},
        "scene": 0,
        "scenes": [{"nodes": scene}],
        "nodes": nodes,
        "meshes": [
            {
                "name": str(mesh.name),
                "primitives": [{"attributes": attributes, "indices": faces, "mode": 4}],
            }
        ],
        "skins": [{"joints": list(range(nj)), "inverseBindMatrices": ibm}],
    }
    if poses is not None:
        t_in = buf.add(keys, _FLOAT, "SCALAR", minmax=True)
        q = _continuous(quat_normalize(pq))
        samplers, channels = [], []
        for j in range(nj):
            for prop, vals, kind in (
                ("translation", pt[:, j], "VEC3"),
                ("rotation", q[:, j], "VEC4"),
                ("scale", ps[:, j], "VEC3"),
            ):
                out = buf.add(vals.astype(np.float32), _FLOAT, kind)
                channels.append({"sampler": len(samplers), "target": {"node": j, "path": prop}})
                samplers.append({"input": t_in, "output": out, "interpolation": "LINEAR"})
        gltf["animations"] = [{"name": animation, "samplers": samplers, "channels": channels}]
    return write_bytes_atomic(p, _encode(gltf, buf, suffix))


def _nodes(mesh: SkinnedMesh, m: dict) -> tuple[list[dict], list[int]]:
    """The joint nodes (rest TRS, children), one node per distinct base transform above
    the roots, and the mesh node; and the scene's root nodes."""
    nj = mesh.num_joints
    q_rest = quat_normalize(m["rest_rotations"])
    nodes: list[dict] = [
        {
            "name": str(mesh.joint_names[j]),
            "translation": m["rest_translations"][j].tolist(),
            "rotation": q_rest[j].tolist(),
            "scale": m["rest_scales"][j].tolist(),
        }
        for j in range(nj)
    ]
    for j in range(nj):
        kids = np.flatnonzero(m["parents"] == j).tolist()
        if kids:
            nodes[j]["children"] = kids
    scene: list[int] = []
    bases: dict[bytes, int] = {}
    for r in np.flatnonzero(m["parents"] < 0).tolist():
        b = m["base_transforms"][r]
        if np.array_equal(b, np.eye(4)):
            scene.append(r)
            continue
        if np.any(b[3] != (0.0, 0.0, 0.0, 1.0)):
            raise FxspaceError(
                f"mesh.base_transforms[{r}] must be affine (last row 0, 0, 0, 1), got {b[3]}"
            )
        key = b.tobytes()
        if key not in bases:
            bases[key] = len(nodes)
            scene.append(len(nodes))
            name = f"{mesh.joint_names[r]}_base"
            nodes.append({"name": name, "matrix": b.T.reshape(-1).tolist(), "children": []})
        nodes[bases[key]]["children"].append(r)
    scene.append(len(nodes))
    nodes.append({"name": str(mesh.name), "mesh": 0, "skin": 0})
    return nodes, scene


def _encode(gltf: dict, buf: _Buffer, suffix: str) -> bytes:
    """The file's bytes: JSON with an embedded base64 buffer (``.gltf``) or GLB chunks."""
    binary = b"".join(buf.chunks)
    gltf["bufferViews"], gltf["accessors"] = buf.views, buf.accessors
    gltf["buffers"] = [{"byteLength": len(binary)}]
    if suffix == ".gltf":
        uri = "data:application/octet-stream;base64," + base64.b64encode(binary).decode("ascii")
        gltf["buffers"][0]["uri"] = uri
        return json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    blob = b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(js), b"JSON"),
            js,
            struct.pack("<I4s", len(binary), b"BIN\0"),
            binary,
        ]
    )
    return blob


@checked
def write_ik_gltf(
    path: str | Path,
    mesh: SkinnedMesh,
    angles,
    translation,
    rate: float = 30.0,
) -> Path:
    """Write IK poses (one ``(J, 3)`` or ``(T, J, 3)``) of ``mesh`` as an animated glTF.

    The glTF counterpart of `fxspace.io.write_ik_bvh` (same arguments), without its
    limits: several roots and non-uniform scales are fine, and the mesh travels with the
    motion. Frames are keyed at ``arange(T) / rate``.

    **Arguments:** `path` (``.glb``/``.gltf``), `mesh` (the skinned mesh the poses belong
    to), `angles`/`translation` (`fxspace.Pose` fields, stacked over frames), `rate`
    (frames per second).

    **Returns:** the path written (atomically).
    """
    return write_gltf(path, mesh, ik_poses_to_local(mesh, angles, translation), rate=rate)


def write_gltf_animation(
    path: str | Path,
    mesh: SkinnedMesh,
    retargeted,
    *,
    rate: float | None = None,
    animation: str = "retargeted",
) -> Path:
    """Write a retargeted take (or any per-frame IK poses) on ``mesh`` as an animated
    glTF an animator opens (Blender, three.js): the character's mesh and skin plus one
    animation with every joint's rotation and the root's translation per frame.

    **Arguments:** `path` (``.glb``/``.gltf``); `mesh`: the character the poses belong to;
    `retargeted`: a `fxspace.mesh.Retargeted` record (its ``.pose`` and ``.rate`` are
    used), or a `fxspace.Pose` with a leading frame axis; `rate`: frames per second
    (default: the record's, else 30); `animation`: the animation's name.

    Non-finite frames (a source frame with NaN) are refused, naming the first.

    **Returns:** the path written (atomically). Read it back with `fxspace.io.read_gltf`
    and pose it with `fxspace.mesh.animation_vertices`.
    """
    pose, r = retargeted_pose(retargeted, rate)
    local = ik_poses_to_local(mesh, pose.angles, pose.translation)
    return write_gltf(path, mesh, local, rate=float(r), animation=animation)
