"""`fx.io.write_gltf_animation`: a retargeted take (or per-frame IK poses) on a character
as a .glb whose animation, read back with `fx.io.read_gltf`, poses the same vertices."""

from __future__ import annotations

import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import FxspaceError


def _reread_vertices(path, n, rate):
    back = fx.io.read_gltf(path)
    assert back.animation_names == ("retargeted",)
    t = np.arange(n) / rate
    return back, fx.mesh.animation_vertices(back, "retargeted", t)


def test_pose_frames_reread_to_the_same_vertices(tmp_path, rng):
    mesh = fx.mesh.chain_mesh(num_joints=6, frames=4)
    n, nj = 8, mesh.num_joints
    angles = np.cumsum(rng.normal(0, 0.1, (n, nj, 3)), axis=0)
    trans = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    pose = fx.Pose(angles, trans)
    p = fx.io.write_gltf_animation(tmp_path / "take.glb", mesh, pose, rate=24.0)
    back, got = _reread_vertices(p, n, 24.0)
    frames = zip(angles, trans, strict=True)
    want = np.stack([np.asarray(fx.pose_vertices(mesh, fx.Pose(a, t))) for a, t in frames])
    assert back.num_vertices == mesh.num_vertices and back.joint_names == mesh.joint_names
    np.testing.assert_allclose(got, want, atol=1e-5 * np.ptp(want))  # float32 in the file


def test_refusals(tmp_path):
    mesh = fx.mesh.chain_mesh(num_joints=4, frames=2)
    with pytest.raises(FxspaceError, match="retarget"):
        fx.io.write_gltf_animation(tmp_path / "x.glb", mesh, np.zeros((2, 4, 3)))
    bad = fx.Pose(np.full((2, 4, 3), np.nan), np.zeros((2, 3)))
    with pytest.raises(FxspaceError, match="NaN"):
        fx.io.write_gltf_animation(tmp_path / "x.glb", mesh, bad)
    with pytest.raises(FxspaceError, match="rate"):
        zero = fx.Pose(np.zeros((2, 4, 3)), np.zeros((2, 3)))
        fx.io.write_gltf_animation(tmp_path / "x.glb", mesh, zero, rate=-1)
    assert not (tmp_path / "x.glb").exists()


@pytest.mark.slow
def test_retargeted_cmu_walk_on_cesium_man_rereads(tmp_path, data_dir):
    man = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    cmu = data_dir / "body" / "cmu" / "131"
    take = fx.io.read_amc(cmu / "131.asf", cmu / "131_09.amc.gz").frames(slice(0, 240, 8))
    jm = fx.motion.joint_map_for(take).correspondences(
        fx.motion.joint_map_for(man.joint_names, required=())
    )
    r = fx.mesh.retarget(take, man, jm, baseline=False)
    p = fx.io.write_gltf_animation(tmp_path / "walk.glb", man, r)
    n = r.pose.angles.shape[0]
    _, got = _reread_vertices(p, n, r.rate)
    want = np.stack(
        [np.asarray(fx.pose_vertices(man, fx.Pose(a, t))) for a, t in zip(*r.pose, strict=True)]
    )
    np.testing.assert_allclose(got, want, atol=1e-5 * r.height)
    # the character travels with the scaled source
    mid, src = got.mean(1), r.targets.mean(1)
    np.testing.assert_allclose(mid[-1] - mid[0], src[-1] - src[0], atol=0.05 * r.height)
