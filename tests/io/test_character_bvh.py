"""`fx.io.write_character_bvh`: a retargeted take as a BVH of the character's own
skeleton (its joint names and rest offsets); read back with `fx.io.read_bvh`, forward
kinematics gives the retargeted joint positions (`fx.mesh.joint_positions`)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import FxspaceError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "mesh"))
from mesh_toys import branching_mesh  # noqa: E402


def _fk(path, mesh):
    """The BVH's joints by forward kinematics, in ``mesh``'s joint order (BVH writes
    depth-first)."""
    mot = fx.io.read_bvh(path)
    assert sorted(mot.names) == sorted(mesh.joint_names)  # the character's skeleton
    x = np.asarray(fx.forward_kinematics(mot))
    return mot, x[:, [mot.names.index(n) for n in mesh.joint_names]]


def test_pose_frames_round_trip_to_joint_positions(tmp_path, rng):
    mesh = branching_mesh(3)  # joints not in depth-first order
    n = 7
    angles = np.cumsum(rng.normal(0, 0.2, (n, mesh.num_joints, 3)), axis=0)
    trans = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    pose = fx.Pose(angles, trans)
    p = fx.io.write_character_bvh(tmp_path / "take.bvh", mesh, pose, rate=24.0)
    mot, got = _fk(p, mesh)
    assert mot.num_frames == n
    assert abs(mot.rate - 24.0) < 1e-4
    want = fx.mesh.joint_positions(mesh, pose)
    np.testing.assert_allclose(got, want, atol=1e-5 * max(1.0, np.ptp(want)))


def test_refusals(tmp_path):
    mesh = fx.mesh.chain_mesh(num_joints=4, frames=2)
    with pytest.raises(FxspaceError, match="retarget"):
        fx.io.write_character_bvh(tmp_path / "x.bvh", mesh, np.zeros((2, 4, 3)))
    ang = np.zeros((3, 4, 3))
    ang[1, 2, 0] = np.nan
    with pytest.raises(FxspaceError, match="frame 1"):
        fx.io.write_character_bvh(tmp_path / "x.bvh", mesh, fx.Pose(ang, np.zeros((3, 3))))
    with pytest.raises(FxspaceError, match="rate"):
        zero = fx.Pose(np.zeros((2, 4, 3)), np.zeros((2, 3)))
        fx.io.write_character_bvh(tmp_path / "x.bvh", mesh, zero, rate=0)
    assert not (tmp_path / "x.bvh").exists()


@pytest.mark.slow
def test_retargeted_cmu_walk_as_cesium_man_bvh(tmp_path, data_dir):
    man = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    cmu = data_dir / "body" / "cmu" / "131"
    take = fx.io.read_amc(cmu / "131.asf", cmu / "131_09.amc.gz").frames(slice(0, 240, 8))
    jm = fx.motion.joint_map_for(take).correspondences(
        fx.motion.joint_map_for(man.joint_names, required=())
    )
    r = fx.mesh.retarget(take, man, jm, baseline=False)
    p = fx.io.write_character_bvh(tmp_path / "walk.bvh", man, r)
    mot, got = _fk(p, man)
    assert mot.num_frames == r.pose.angles.shape[0] and abs(mot.rate - r.rate) < 1e-3
    want = fx.mesh.joint_positions(man, r.pose)
    np.testing.assert_allclose(got, want, atol=1e-5 * r.height)
    # the corresponded joints read back are the record's own (its .joints)
    idx = [man.joint_names.index(c) for _, c in r.correspondences]
    np.testing.assert_allclose(got[:, idx], r.joints, atol=1e-4 * r.height)
