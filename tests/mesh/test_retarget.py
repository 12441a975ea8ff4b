"""Retargeting by the mesh IK (`fx.mesh.retarget`): a source that is the character's own
skeleton animation comes back exactly; real CMU and Bandai walks onto CesiumMan."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_toys import branching_mesh

import fxspace as fx
from fxspace.mesh._retarget_kinematics import _global_frames_np
from fxspace.rotations import matrix_to_quat


def _own_motion(mesh, angles, trans, rate=30.0):
    """The character's own animation as a skeletal Motion (world frames → local rotations,
    rest translations as offsets)."""
    g = _global_frames_np(mesh, angles, trans)
    par = np.asarray(mesh.parents)
    r = g[..., :3, :3]
    x = g[..., :3, 3]
    nj = mesh.num_joints
    loc = np.empty_like(r)
    off = np.zeros((nj, 3))
    for j in range(nj):
        if par[j] < 0:
            loc[:, j] = r[:, j]
        else:
            loc[:, j] = np.swapaxes(r[:, par[j]], -1, -2) @ r[:, j]
            off[j] = r[0, par[j]].T @ (x[0, j] - x[0, par[j]])
    return fx.motion.Motion(
        names=tuple(mesh.joint_names),
        parents=tuple(int(p) for p in par),
        offsets=off,
        root_translation=x[:, 0],
        rotations=np.asarray(matrix_to_quat(loc)),
        rate=rate,
        channels=((),) * nj,
    )


def _walk(rng, nj, frames=24):
    steps = rng.normal(0, 0.04, (frames, nj, 3))
    angles = np.cumsum(steps, axis=0)
    trans = np.cumsum(rng.normal(0, 0.01, (frames, 3)), axis=0)
    return angles, trans


def test_own_animation_retargets_to_itself(rng):
    mesh = branching_mesh(3)
    angles, trans = _walk(rng, mesh.num_joints)
    motion = _own_motion(mesh, angles, trans)
    r = fx.mesh.retarget(motion, mesh, feet=[])  # same names: paired without a map
    assert r.result == fx.RESULTS.successful
    assert r.scale == pytest.approx(1.0, rel=1e-9)
    assert r.pose.angles.shape == (24, mesh.num_joints, 3) and r.pose.translation.shape == (24, 3)
    assert np.nanmax(r.joint_error) < 1e-3, r.joint_error
    # the solved pose puts every joint where the source's is (up to the floor shift)
    xj = fx.mesh.joint_positions(mesh, r.pose)
    np.testing.assert_allclose(xj - xj[:, :1], r.targets - r.targets[:, :1], atol=1e-3 * r.height)
    # rotation copying of one's own skeleton is exact too
    assert np.nanmax(r.baseline.joint_error) < 1e-6
    assert r.ms_per_frame > 0 and np.isnan(r.foot_slide).all()


def test_refusals_name_the_fix(rng):
    mesh = branching_mesh(3)
    angles, trans = _walk(rng, mesh.num_joints, 4)
    motion = _own_motion(mesh, angles, trans)
    with pytest.raises(fx.mesh.RetargetError, match="joints are"):
        fx.mesh.retarget(motion, mesh, {"j0": "j0", "nope": "j1", "j2": "j2", "j3": "j3"})
    with pytest.raises(fx.mesh.RetargetError, match="at least 4"):
        fx.mesh.retarget(motion, mesh, [("j0", "j0"), ("j1", "j1")])
    with pytest.raises(fx.mesh.RetargetError, match="skeletal motion"):
        fx.mesh.retarget(np.zeros((3, 3)), mesh)
    with pytest.raises(fx.mesh.RetargetError, match="SkinnedMesh"):
        fx.mesh.retarget(motion, "CesiumMan.glb")


@pytest.mark.slow
def test_nan_frames_are_reported_not_hidden(rng):
    mesh = branching_mesh(3)
    angles, trans = _walk(rng, mesh.num_joints)
    motion = _own_motion(mesh, angles, trans)
    rt = np.array(motion.root_translation)
    rt[5] = np.nan
    import dataclasses

    r = fx.mesh.retarget(dataclasses.replace(motion, root_translation=rt), mesh, feet=[])
    assert r.result == fx.RESULTS.nonfinite_input
    assert np.isnan(r.joint_error[5]) and np.nanmax(r.joint_error) < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("take", ["cmu", "bandai"])
def test_real_walk_onto_cesium_man(data_dir, take):
    man = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    body = data_dir / "body"
    if take == "cmu":
        m = fx.io.read_amc(body / "cmu" / "131" / "131.asf", body / "cmu" / "131" / "131_09.amc.gz")
        m = m.frames(slice(0, 480, 4))
    else:
        m = fx.io.read_bvh(body / "bandai" / "dataset-1_walk_normal_001.bvh.gz", units="cm")
    jm = fx.motion.joint_map_for(m).correspondences(
        fx.motion.joint_map_for(man.joint_names, required=())
    )
    assert len(jm) >= 14
    # the resolver itself as the map: the same pairs
    r = fx.mesh.retarget(m, man, fx.motion.joint_map_for)
    assert r.correspondences == tuple((s, c) for _, s, c in jm)
    s, c = r.summary(), r.baseline.summary()
    assert r.result == fx.RESULTS.successful
    assert s["joint_error_median"] < 0.06 and s["joint_error_median"] < c["joint_error_median"]
    assert r.contacts.any()
    assert s["foot_slide_mean"] <= s["source_foot_slide_mean"] * 1.05


@pytest.mark.slow
def test_live_retarget_follows_its_own_skeleton_frame_by_frame(rng):
    mesh = branching_mesh(3)
    angles, trans = _walk(rng, mesh.num_joints, 10)
    motion = _own_motion(mesh, angles, trans)
    lr = fx.mesh.live_retarget(motion, mesh)
    x = fx.motion.forward_kinematics(motion)
    assert lr.scale == pytest.approx(1.0, rel=1e-9)
    for t in range(10):
        pose, v = lr.step(np.asarray(x[t]))
        xj = fx.mesh.joint_positions(mesh, pose)
        tgt = lr.targets(np.asarray(x[t]))
        np.testing.assert_allclose(xj, tgt, atol=1e-3 * lr.height)
        assert v.shape == (mesh.num_vertices, 3)


def test_default_joint_map_pairs_by_role_across_naming_styles():
    """joint_map=None uses the one joint-name map (fxspace.joints): a Mixamo-named source
    pairs with a VRM-named character by role, not by spelling; unknown names fall back to
    joints of the same name."""
    from fxspace.mesh._retarget_inputs import _pairs

    sides = ("UpLeg", "Leg", "Foot", "ToeBase", "Shoulder", "Arm", "ForeArm", "Hand")
    vrm_sides = ("UpperLeg", "LowerLeg", "Foot", "Toes", "Shoulder", "UpperArm", "LowerArm",
                 "Hand")  # fmt: skip
    mix = ["Hips", "Spine", "Spine1", "Spine2", "Neck", "Head"]
    mix += [f"{s}{b}" for s in ("Left", "Right") for b in sides]
    vrm = ["hips", "spine", "chest", "upperChest", "neck", "head"]
    vrm += [f"{s}{b}" for s in ("left", "right") for b in vrm_sides]
    pairs, roles = _pairs(None, mix, vrm)
    got = dict(pairs)
    assert got["LeftUpLeg"] == "leftUpperLeg" and got["RightForeArm"] == "rightLowerArm"
    assert got["Spine1"] == "chest" and "left_upper_leg" in roles
    same = ["a", "b", "c", "d", "e"]
    pairs, roles = _pairs(None, same, list(reversed(same)))
    assert sorted(pairs) == [(n, n) for n in same] and roles == [""] * 5
