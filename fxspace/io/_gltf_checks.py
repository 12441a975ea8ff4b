"""The checks of `fxspace.io.write_gltf`'s inputs (mesh, poses, key times, IK poses).

Each turns its argument into float64 arrays of the shapes the writer needs, or raises an
`fxspace.errors.FxspaceError` naming the argument, the shape or value wanted and the fix.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.mesh import LocalPose

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh import SkinnedMesh


def _finite_array(x, name: str, shape: tuple[int | None, ...], want: str) -> np.ndarray:
    """``x`` as float64 with ``shape`` (``None`` = any size), finite, else a clear error."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise FxspaceError(f"{name} must be a numeric array {want}, got {type(x).__name__}") from e
    if a.ndim != len(shape) or any(
        s is not None and s != n for s, n in zip(shape, a.shape, strict=True)
    ):
        raise FxspaceError(f"{name} must have shape {want}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        where = np.argwhere(bad)[:3].tolist()
        raise FxspaceError(
            f"{name} holds {int(bad.sum())} NaN/inf value(s) (first at {where}); "
            "only finite values can be exported"
        )
    return a


def _check_ik(mesh: SkinnedMesh, angles, translation) -> tuple[np.ndarray, np.ndarray, bool]:
    """``(angles (T, J, 3), translation (T, 3), single)``; the checks of ``write_ik_bvh``."""
    nj = mesh.num_joints
    single = np.ndim(angles) == 2
    if single:
        ang = _finite_array(angles, "angles", (nj, 3), f"({nj}, 3) or (T, {nj}, 3)")[None]
        tr = _finite_array(translation, "translation", (3,), "(3,) for one pose (J, 3)")[None]
    else:
        ang = _finite_array(angles, "angles", (None, nj, 3), f"(T, {nj}, 3) or ({nj}, 3)")
        tr = _finite_array(
            translation, "translation", (ang.shape[0], 3), f"(T={ang.shape[0]}, 3) like angles"
        )
    if ang.shape[0] == 0:
        raise FxspaceError("angles holds no frames; pass at least one pose (J, 3)")
    return ang, tr, single


def _check_mesh(mesh: SkinnedMesh) -> dict[str, np.ndarray]:
    nj, nv = mesh.num_joints, mesh.num_vertices
    if nj == 0 or nv == 0:
        raise FxspaceError(f"mesh {mesh.name!r} needs at least one joint and one vertex")
    out = {
        "vertices": _finite_array(mesh.vertices, "mesh.vertices", (nv, 3), "(V, 3)"),
        "rest_translations": _finite_array(
            mesh.rest_translations, "mesh.rest_translations", (nj, 3), "(J, 3)"
        ),
        "rest_rotations": _finite_array(
            mesh.rest_rotations, "mesh.rest_rotations", (nj, 4), "(J, 4)"
        ),
        "rest_scales": _finite_array(mesh.rest_scales, "mesh.rest_scales", (nj, 3), "(J, 3)"),
        "base_transforms": _finite_array(
            mesh.base_transforms, "mesh.base_transforms", (nj, 4, 4), "(J, 4, 4)"
        ),
        "inverse_bind": _finite_array(
            mesh.inverse_bind, "mesh.inverse_bind", (nj, 4, 4), "(J, 4, 4)"
        ),
        "skin_weights": _finite_array(mesh.skin_weights, "mesh.skin_weights", (nv, None), "(V, I)"),
    }
    faces = np.asarray(mesh.faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise FxspaceError(f"mesh.faces must be (F, 3) triangles with F ≥ 1, got {faces.shape}")
    if faces.min() < 0 or faces.max() >= nv:
        raise FxspaceError(f"mesh.faces must index the mesh's {nv} vertices")
    sj = np.asarray(mesh.skin_joints)
    if sj.shape != out["skin_weights"].shape:
        raise FxspaceError(
            f"mesh.skin_joints {sj.shape} and mesh.skin_weights "
            f"{out['skin_weights'].shape} must both be (V, I)"
        )
    if sj.size and (sj.min() < 0 or sj.max() >= nj):
        raise FxspaceError(f"mesh.skin_joints must index the mesh's {nj} joints")
    w = out["skin_weights"]
    if np.any(w < 0) or np.any(w.sum(axis=1) <= 0):
        raise FxspaceError(
            "mesh.skin_weights must be ≥ 0 with a positive sum on every vertex "
            "(glTF WEIGHTS_n hold a convex combination)"
        )
    if np.any(np.linalg.norm(out["rest_rotations"], axis=1) < 1e-12):
        raise FxspaceError("mesh.rest_rotations holds a zero quaternion")
    parents = np.asarray(mesh.parents)
    if parents.shape != (nj,) or np.any(parents >= np.arange(nj)) or np.any(parents < -1):
        raise FxspaceError(
            "mesh.parents must be (J,) with parents[j] < j (-1 for a root), as read_gltf gives"
        )
    out["faces"], out["skin_joints"], out["parents"] = faces, sj, parents
    return out


def _check_poses(poses, nj: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(poses, LocalPose):
        raise FxspaceError(
            f"poses must be a LocalPose (e.g. mesh.sample_animation(name, times)), "
            f"got {type(poses).__name__}"
        )
    nd = np.ndim(poses.rotations)
    lead = (None, nj) if nd == 3 else (nj,)
    want = "(T, J, {c}) or (J, {c})".replace("J", str(nj))
    t = _finite_array(poses.translations, "poses.translations", (*lead, 3), want.format(c=3))
    q = _finite_array(poses.rotations, "poses.rotations", (*lead, 4), want.format(c=4))
    s = _finite_array(poses.scales, "poses.scales", (*lead, 3), want.format(c=3))
    if nd != 3:
        t, q, s = t[None], q[None], s[None]
    if not t.shape[0] == q.shape[0] == s.shape[0] >= 1:
        raise FxspaceError(
            f"poses.translations/rotations/scales must share the frame count T ≥ 1, got "
            f"{t.shape[0]}/{q.shape[0]}/{s.shape[0]}"
        )
    if np.any(np.linalg.norm(q, axis=-1) < 1e-12):
        raise FxspaceError("poses.rotations holds a zero quaternion; rotations must be unit")
    return t, q, s


def _check_times(times, rate, n: int) -> np.ndarray:
    if times is None:
        if isinstance(rate, bool) or not isinstance(rate, int | float | np.number):
            raise FxspaceError(f"rate must be a number (frames per second), got {rate!r}")
        if not (math.isfinite(rate) and rate > 0):
            raise FxspaceError(f"rate must be finite and > 0 (frames per second), got {rate!r}")
        times = np.arange(n) / float(rate)
    t = _finite_array(times, "times", (n,), f"(T={n},) seconds, one per pose")
    t32 = t.astype(np.float32)
    if t32[0] < 0:
        raise FxspaceError(f"times must be ≥ 0 (glTF key times), got times[0] = {t[0]}")
    dec = np.flatnonzero(np.diff(t32) <= 0)
    if dec.size:
        i = int(dec[0])
        raise FxspaceError(
            f"times must be strictly increasing (glTF key times, float32), but times[{i}] = "
            f"{t[i]} ≥ times[{i + 1}] = {t[i + 1]}; sort the poses or space the times apart"
        )
    return t32
