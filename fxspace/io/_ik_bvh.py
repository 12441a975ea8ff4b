"""Write mesh-IK poses (per-joint Euler angles on a glTF skeleton) as BVH.

A `fxspace.Pose` rotates joint ``j`` by ``R_rest,j · R_x R_y R_z(θ_j)`` and moves
the skeleton by a world translation. BVH has no rest rotations and no scales, so the
writer bakes them: each joint's BVH rotation is the full local rotation
``R_rest,j · E(θ_j)`` (the base transform's rotation in front for the root), each offset
is the rest translation times the parent's accumulated uniform scale, and the root
position is ``base · t_root + translation``. Skeletons with several roots or non-uniform
scales are refused. Round trip: ``fx.io.read_bvh`` + ``fx.forward_kinematics`` give the
IK joint origins.

Example: ``fx.io.write_ik_bvh("pose.bvh", mesh, res.pose.angles, res.pose.translation)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.io._bvh import write_bvh
from fxspace.motion import Motion
from fxspace.rotations import euler_to_matrix, matrix_to_quat, quat_normalize, quat_to_matrix

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh import SkinnedMesh

__all__ = ["ik_poses_to_motion", "write_character_bvh", "write_ik_bvh"]

_ROT = ("Xrotation", "Yrotation", "Zrotation")


@checked
def ik_poses_to_motion(
    mesh: SkinnedMesh, angles: np.ndarray, translation: np.ndarray, rate: float = 30.0
) -> Motion:
    """A `fxspace.io.Motion` of IK poses ``angles (T, J, 3)``, ``translation (T, 3)``."""
    ang = np.asarray(angles, np.float64)
    tr = np.asarray(translation, np.float64)
    nj = mesh.num_joints
    if ang.ndim == 2:
        ang, tr = ang[None], tr.reshape(1, 3)
    if ang.shape[1:] != (nj, 3) or tr.shape != (ang.shape[0], 3):
        raise FxspaceError(f"angles must be (T, {nj}, 3) and translation (T, 3)")
    if not (np.isfinite(ang).all() and np.isfinite(tr).all()):
        raise FxspaceError("angles and translation must be finite to export")
    parents = np.asarray(mesh.parents)
    if (parents < 0).sum() != 1 or parents[0] != -1:
        raise FxspaceError(f"{mesh.name}: BVH needs a single root joint (joint 0)")
    s = np.asarray(mesh.rest_scales, np.float64)
    if np.any(np.abs(s - s[:, :1]) > 1e-5 * np.abs(s).max(axis=1, keepdims=True)):
        raise FxspaceError(f"{mesh.name}: non-uniform joint scales cannot be written as BVH")
    base = np.asarray(mesh.base_transforms[0], np.float64)
    sigma_b = float(np.cbrt(abs(np.linalg.det(base[:3, :3]))))
    cum = np.zeros(nj)  # accumulated uniform scale of each joint's frame
    for j in range(nj):
        cum[j] = (sigma_b if parents[j] < 0 else cum[parents[j]]) * s[j, 0]
    t_rest = np.asarray(mesh.rest_translations, np.float64)
    offsets = np.zeros((nj, 3))
    for j in range(1, nj):
        offsets[j] = cum[parents[j]] * t_rest[j]
    r_rest = np.asarray(quat_to_matrix(quat_normalize(mesh.rest_rotations), order="xyzw"))
    local = r_rest[None] @ np.asarray(euler_to_matrix(ang, "XYZ"))  # (T, J, 3, 3)
    local[:, 0] = (base[:3, :3] / sigma_b) @ local[:, 0]
    quats = np.asarray(matrix_to_quat(local, order="wxyz"))
    root = base[:3, :3] @ t_rest[0] + base[:3, 3] + tr
    channels = tuple(
        ("Xposition", "Yposition", "Zposition", *_ROT) if j == 0 else _ROT for j in range(nj)
    )
    return Motion(
        names=tuple(mesh.joint_names),
        parents=tuple(int(p) for p in parents),
        offsets=offsets,
        root_translation=root,
        rotations=quats,
        rate=float(rate),
        channels=channels,
    )


@checked
def write_ik_bvh(
    path: str | Path,
    mesh: SkinnedMesh,
    angles: np.ndarray,
    translation: np.ndarray,
    rate: float = 30.0,
) -> Path:
    """Write IK poses (one frame ``(J, 3)`` or ``(T, J, 3)``) of ``mesh`` as BVH.

    **Arguments:** `path` (``.bvh``/``.bvh.gz``), `mesh` (the skinned mesh the poses
    belong to), `angles`/`translation` (`fxspace.Pose` fields, stacked over
    frames), `rate` (frames per second).

    **Returns:** the path written (atomically).
    """

    return write_bvh(path, ik_poses_to_motion(mesh, angles, translation, rate))


def retargeted_pose(retargeted, rate) -> tuple:
    """``(pose, rate)`` of a `fx.mesh.retarget` record (or a bare ``Pose``) and the frame
    rate to write it at (``rate``, else the record's, else 30), checked."""
    pose = getattr(retargeted, "pose", retargeted)
    if not (hasattr(pose, "angles") and hasattr(pose, "translation")):
        raise FxspaceError(
            "retargeted must be a fx.mesh.retarget(...) record or a Pose (angles (T, J, 3), "
            f"translation (T, 3)), got {type(retargeted).__name__}"
        )
    r = rate if rate is not None else getattr(retargeted, "rate", None) or 30.0
    if not (isinstance(r, int | float) and np.isfinite(r) and r > 0):
        raise FxspaceError(f"rate must be a positive number of frames per second, got {r!r}")
    return pose, float(r)


@checked
def write_character_bvh(
    path: str | Path, mesh: SkinnedMesh, retargeted, *, rate: float | None = None
) -> Path:
    """Write a retargeted take as a BVH of the character's own skeleton: the hierarchy
    is ``mesh``'s joints (its joint names, offsets from the glTF skin's rest
    translations), each frame the joints' rotations and the root's position.

    **Arguments:** `path` (``.bvh``/``.bvh.gz``); `mesh`: the character the take was
    retargeted onto; `retargeted`: a `fxspace.mesh.retarget` record (its ``.pose`` and
    ``.rate`` are used) or a `fxspace.Pose` with a leading frame axis; `rate`: frames
    per second (default: the record's, else 30).

    Non-finite frames (a source frame with NaN) are refused, naming the first.

    **Returns:** the path written (atomically). ``fx.io.read_bvh`` +
    ``fx.forward_kinematics`` give ``fx.mesh.joint_positions(mesh, retargeted.pose)``.
    """
    pose, r = retargeted_pose(retargeted, rate)
    ang = np.asarray(pose.angles, np.float64)
    tr = np.asarray(pose.translation, np.float64)
    if ang.ndim == 3 and tr.ndim == 2 and ang.shape[0] == tr.shape[0]:
        bad = ~(np.isfinite(ang).all(axis=(1, 2)) & np.isfinite(tr).all(axis=1))
        if bad.any():
            raise FxspaceError(
                f"retargeted: frame {int(np.argmax(bad))} is not finite (a source frame "
                "with NaN?); drop or fill those frames before exporting"
            )
    return write_ik_bvh(path, mesh, ang, tr, rate=float(r))
