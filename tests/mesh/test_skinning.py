"""Linear blend skinning, poses and surface markers."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.errors import FxspaceError
from fxspace.io import LocalPose, SkinnedMesh
from fxspace.mesh._skinning import ancestor_table, euler_to_matrix, quaternion_to_matrix


def two_bone_mesh() -> SkinnedMesh:
    """Bone 0 at the origin, bone 1 at (0, 1, 0); a column of vertices along y."""
    ys = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    verts = np.stack([np.zeros(5), ys, np.zeros(5)], axis=1)
    w1 = np.clip(ys - 0.5, 0.0, 1.0)  # 0, 0, .5, 1, 1 on bone 1
    ibm = np.tile(np.eye(4), (2, 1, 1))
    ibm[1, 1, 3] = -1.0
    return SkinnedMesh(
        name="two_bone",
        vertices=verts,
        faces=np.array([[0, 1, 2], [2, 3, 4]], dtype=np.int32),
        joint_names=("b0", "b1"),
        joint_nodes=(0, 1),
        parents=np.array([-1, 0], dtype=np.int32),
        rest_translations=np.array([[0.0, 0, 0], [0, 1, 0]]),
        rest_rotations=np.array([[0.0, 0, 0, 1], [0, 0, 0, 1]]),
        rest_scales=np.ones((2, 3)),
        base_transforms=np.tile(np.eye(4), (2, 1, 1)),
        inverse_bind=ibm,
        skin_joints=np.tile(np.array([0, 1], dtype=np.int32), (5, 1)),
        skin_weights=np.stack([1 - w1, w1], axis=1),
        animations={},
    )


def test_rotation_helpers_match_scipy(rng):
    q = Rotation.random(5, random_state=1).as_quat()
    np.testing.assert_allclose(
        quaternion_to_matrix(jnp.asarray(q)), Rotation.from_quat(q).as_matrix(), atol=1e-12
    )
    e = rng.uniform(-3, 3, (5, 3))
    np.testing.assert_allclose(
        euler_to_matrix(jnp.asarray(e)), Rotation.from_euler("XYZ", e).as_matrix(), atol=1e-12
    )


def test_ancestor_table():
    np.testing.assert_array_equal(
        ancestor_table([-1, 0, 1, 0]), [[0, 4, 4], [1, 0, 4], [2, 1, 0], [3, 0, 4]]
    )
    with pytest.raises(FxspaceError, match="cycle"):
        ancestor_table([1, 0])


def test_rest_pose_returns_bind_pose():
    m = two_bone_mesh()
    np.testing.assert_allclose(fx.mesh.rest_vertices(m), m.vertices, atol=1e-12)
    np.testing.assert_allclose(fx.pose_vertices(m, fx.rest_pose(m)), m.vertices, atol=1e-12)


def test_two_bone_by_hand():
    m = two_bone_mesh()
    # bone 1 turns 90° about z: x' = -(y - 1), y' = 1
    pose = fx.Pose(jnp.array([[0.0, 0, 0], [0, 0, np.pi / 2]]), jnp.array([0.0, 0.0, 0.0]))
    v = np.asarray(fx.pose_vertices(m, pose))
    rigid1 = np.array([[0, 0, 0], [0, 0.5, 0], [0, 1, 0], [-0.5, 1, 0], [-1, 1, 0]])
    expect = m.vertices.copy()
    expect[2] = 0.5 * m.vertices[2] + 0.5 * rigid1[2]  # the vertex at the joint is fixed anyway
    expect[3:] = rigid1[3:]
    np.testing.assert_allclose(v, expect, atol=1e-12)
    # a 50/50 vertex away from the joint: blend of the two rigid maps (LBS, not rigid)
    m2 = dataclasses.replace(m, skin_weights=np.full((5, 2), 0.5))
    v2 = np.asarray(fx.pose_vertices(m2, pose))
    np.testing.assert_allclose(v2[4], 0.5 * np.array([0, 2, 0]) + 0.5 * np.array([-1, 1, 0]))
    # the same through local transforms (quaternions) and with a root translation
    lp = LocalPose(
        m.rest_translations + [[1.0, 0, 0], [0, 0, 0]],
        np.array([[0, 0, 0, 1.0], Rotation.from_euler("z", 90, degrees=True).as_quat()]),
        np.ones((2, 3)),
    )
    np.testing.assert_allclose(fx.skin_local_pose(m, lp), expect + [1.0, 0, 0], atol=1e-12)


def test_lbs_function_and_jit_vmap(rng):
    m = two_bone_mesh()
    mats = jnp.asarray(np.tile(np.eye(4), (2, 1, 1)))
    mats = mats.at[1, :3, 3].set(jnp.array([1.0, 2.0, 3.0]))
    args = (jnp.asarray(m.vertices), jnp.asarray(m.skin_joints), jnp.asarray(m.skin_weights))
    out = fx.linear_blend_skinning(*args, mats)
    np.testing.assert_allclose(out, m.vertices + m.skin_weights[:, 1:2] * [1.0, 2.0, 3.0])
    np.testing.assert_allclose(jax.jit(fx.linear_blend_skinning)(*args, mats), out)
    poses = fx.Pose(jnp.asarray(rng.normal(size=(4, 2, 3))), jnp.asarray(rng.normal(size=(4, 3))))
    batched = jax.vmap(lambda p: fx.pose_vertices(m, p))(poses)
    for i in range(4):
        one = fx.pose_vertices(m, fx.Pose(poses.angles[i], poses.translation[i]))
        np.testing.assert_allclose(batched[i], one, atol=1e-12)


def test_pose_from_local_reproduces_animation(data_dir):
    m = fx.io.read_gltf(data_dir / "mesh" / "Fox.glb")
    t = np.linspace(0.0, 0.7, 3)
    truth = fx.mesh.animation_vertices(m, "Walk", t)
    p = fx.pose_from_local(m, m.sample_animation("Walk", t))
    got = jax.vmap(lambda a, b: fx.pose_vertices(m, fx.Pose(a, b)))(p.angles, p.translation)
    np.testing.assert_allclose(got, truth, atol=1e-8)


def cube():
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    f = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )
    return v, f


def test_visibility_splits_closed_mesh():
    v, f = cube()
    n = np.asarray(fx.triangle_normals(v, f))
    centre = v[f].mean(axis=1) - 0.5
    assert np.all(np.einsum("fc,fc->f", n, centre) > 0)  # outward (counter-clockwise) faces
    for d in ([0.3, -0.5, 1.0], [1.0, 0.0, 0.0], [-0.2, 0.9, 0.1]):
        a = np.asarray(fx.visible_triangles(v, f, np.asarray(d)))
        b = np.asarray(fx.visible_triangles(v, f, -np.asarray(d)))
        perpendicular = np.isclose(n @ np.asarray(d), 0.0)
        assert not np.any(a & b)
        np.testing.assert_array_equal(a | b, ~perpendicular)
        assert 0 < a.sum() < len(f)
    # looking along -z (camera on +z) shows exactly the two z = 1 triangles
    front = np.asarray(fx.visible_triangles(v, f, np.array([0.0, 0.0, -1.0])))
    np.testing.assert_array_equal(np.flatnonzero(front), [10, 11])


def test_place_markers(rng):
    v, f = cube()
    ms = fx.place_markers(v, f, 2, (0.0, 0.0, -1.0), seed=3)
    assert sorted(np.asarray(ms.triangles).tolist()) == [10, 11]
    b = np.asarray(ms.barycentric)
    assert np.all(b >= 0) and np.allclose(b.sum(1), 1.0)
    p = np.asarray(fx.marker_positions(v, f, ms))
    np.testing.assert_allclose(p[:, 2], 1.0)  # on the z = 1 face
    with pytest.raises(FxspaceError, match="exceeds"):
        fx.place_markers(v, f, 3, (0.0, 0.0, -1.0))
    with pytest.raises(FxspaceError, match="do not face"):
        fx.place_markers(v, f, 1, (0.0, 0.0, -1.0), triangles=[0])
    chosen = fx.place_markers(
        v, f, 1, (0.0, 0.0, -1.0), triangles=[10], barycentric=[[1.0, 0.0, 0.0]]
    )
    np.testing.assert_allclose(fx.marker_positions(v, f, chosen), v[f[10, 0]][None])


def test_marker_skinning_is_exact(data_dir, rng):
    """Markers skinned through their (joint, weight, offset) influences equal the barycentric
    blend of the skinned triangle corners, for any pose."""
    m = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    ms = fx.place_markers(m.vertices, m.faces, 30, seed=1)
    model = fx.ik_model(m, ms)
    pose = fx.Pose(jnp.asarray(rng.normal(0, 0.4, (m.num_joints, 3))), jnp.asarray([0.1, 0.2, 0.3]))
    via_mesh = fx.marker_positions(fx.pose_vertices(m, pose), m.faces, ms)
    np.testing.assert_allclose(fx.ik_markers(model, pose), via_mesh, atol=1e-12)
