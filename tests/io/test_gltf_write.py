"""glTF export of skinned meshes, their animations and IK poses: write → read_gltf round
trips on the real meshes, IK poses checked against ``fx.pose_vertices`` (an independent
path: reader + glTF skinning vs the IK skinning), known answers, and refusals."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.errors import FxspaceError

MESHES = ("CesiumMan", "Fox", "RiggedSimple")


@pytest.fixture(scope="module")
def meshes(data_dir):
    return {n: fx.io.read_gltf(data_dir / "mesh" / f"{n}.glb") for n in MESHES}


def _size(mesh) -> float:
    return float(np.ptp(mesh.vertices, axis=0).max())


def _dense_weights(mesh) -> np.ndarray:
    w = np.zeros((mesh.num_vertices, mesh.num_joints))
    rows = np.repeat(np.arange(mesh.num_vertices), mesh.skin_joints.shape[1])
    np.add.at(w, (rows, mesh.skin_joints.reshape(-1)), mesh.skin_weights.reshape(-1))
    return w


def _ik_vertices(mesh, angles, translation) -> np.ndarray:
    f = jax.jit(jax.vmap(lambda a, t: fx.pose_vertices(mesh, fx.Pose(a, t))))
    return np.asarray(f(jnp.asarray(angles), jnp.asarray(translation)))


def _two_roots(mesh):
    """``mesh`` with joint 2 made a second root, both roots under non-identity
    similarities (rotation · uniform scale + translation)."""
    base = np.tile(np.eye(4), (mesh.num_joints, 1, 1))
    base[0, :3, :3] = 1.7 * Rotation.from_rotvec([0.3, -0.5, 0.9]).as_matrix()
    base[0, :3, 3] = [0.2, -1.0, 0.5]
    base[2, :3, :3] = 0.6 * Rotation.from_rotvec([-1.0, 0.2, 0.1]).as_matrix()
    base[2, :3, 3] = [1.0, 0.3, -0.4]
    parents = np.asarray(mesh.parents).copy()
    parents[2] = -1
    return dataclasses.replace(mesh, base_transforms=base, parents=parents)


@pytest.mark.parametrize("name", MESHES)
def test_animation_round_trip(meshes, name, tmp_path):
    mesh = meshes[name]
    anim = mesh.animation_names[-1]
    t = np.linspace(*mesh.animation_range(anim), 10)
    path = fx.io.write_gltf(tmp_path / f"{name}.glb", mesh, mesh.sample_animation(anim, t), t)
    back = fx.io.read_gltf(path)
    size = _size(mesh)
    # the mesh: float32 positions / matrices, the rest of the skeleton exactly (JSON)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-6 * size)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    np.testing.assert_array_equal(back.parents, mesh.parents)
    assert back.joint_names == mesh.joint_names and back.joint_nodes == tuple(
        range(mesh.num_joints)
    )
    np.testing.assert_allclose(_dense_weights(back), _dense_weights(mesh), atol=1e-6)
    np.testing.assert_allclose(back.rest_translations, mesh.rest_translations, rtol=1e-12)
    np.testing.assert_allclose(back.rest_scales, mesh.rest_scales, rtol=1e-12)
    np.testing.assert_allclose(back.rest_rotations, mesh.rest_rotations, atol=1e-12)
    np.testing.assert_allclose(back.base_transforms, mesh.base_transforms, atol=1e-12)
    np.testing.assert_allclose(back.inverse_bind, mesh.inverse_bind, atol=1e-6 * size + 1e-6)
    # the animation: its keys, and the posed vertices
    assert back.animation_names == ("fxspace",)
    lo, hi = back.animation_range("fxspace")
    assert abs(lo - t[0]) < 1e-6 and abs(hi - t[-1]) < 1e-6
    np.testing.assert_allclose(
        fx.mesh.animation_vertices(back, "fxspace", t),
        fx.mesh.animation_vertices(mesh, anim, t),
        atol=1e-5 * size,
    )


def test_independent_readers_agree(meshes, tmp_path):
    """trimesh (a separate glTF loader) reads the same geometry; pygltflib sees the skin."""
    trimesh = pytest.importorskip("trimesh")
    import pygltflib

    mesh = meshes["Fox"]
    path = fx.io.write_gltf(tmp_path / "fox.glb", mesh)
    scene = trimesh.load(path, process=False)
    (geom,) = scene.geometry.values()
    np.testing.assert_allclose(geom.vertices, mesh.vertices, atol=1e-6 * _size(mesh))
    np.testing.assert_array_equal(geom.faces, mesh.faces)
    g = pygltflib.GLTF2().load(str(path))
    assert g.skins[0].joints == list(range(mesh.num_joints)) and not g.animations


@pytest.mark.parametrize("name", ["CesiumMan", "two_roots"])
def test_ik_round_trip(meshes, name, tmp_path):
    """IK poses → write_ik_gltf → read_gltf → glTF skinning = fx.pose_vertices, frame by frame."""
    mesh = meshes["CesiumMan"] if name == "CesiumMan" else _two_roots(meshes["RiggedSimple"])
    size = _size(mesh)
    rng = np.random.default_rng(0)
    ang = rng.normal(0.0, 0.3, (4, mesh.num_joints, 3))
    tr = rng.normal(0.0, 0.2 * size, (4, 3))
    path = fx.io.write_ik_gltf(tmp_path / "ik.gltf", mesh, ang, tr, rate=24.0)  # data-URI JSON
    back = fx.io.read_gltf(path)
    if name == "two_roots":
        np.testing.assert_array_equal(back.parents, mesh.parents)
        np.testing.assert_allclose(back.base_transforms, mesh.base_transforms, atol=1e-12)
    assert back.animation_range("fxspace") == pytest.approx((0.0, 3 / 24.0))
    got = fx.mesh.animation_vertices(back, "fxspace", np.arange(4) / 24.0)
    want = _ik_vertices(mesh, ang, tr)
    assert np.abs(want - mesh.vertices).max() > 0.05 * size  # the poses do move the mesh
    np.testing.assert_allclose(got, want, atol=1e-5 * size)


def test_ik_poses_to_local_matches_pose_vertices(meshes):
    mesh = _two_roots(meshes["RiggedSimple"])
    size = _size(mesh)
    rng = np.random.default_rng(1)
    ang = rng.normal(0.0, 0.5, (5, mesh.num_joints, 3))
    tr = rng.normal(0.0, 0.3 * size, (5, 3))
    local = fx.io.ik_poses_to_local(mesh, ang, tr)
    assert local.rotations.shape == (5, mesh.num_joints, 4)
    np.testing.assert_allclose(np.linalg.norm(local.rotations, axis=-1), 1.0, atol=1e-12)
    got = np.asarray(fx.skin_local_pose(mesh, local))
    np.testing.assert_allclose(got, _ik_vertices(mesh, ang, tr), atol=1e-10 * size)
    # one pose keeps its (J, ·) shape
    one = fx.io.ik_poses_to_local(mesh, ang[2], tr[2])
    assert one.translations.shape == (mesh.num_joints, 3)
    np.testing.assert_allclose(np.asarray(fx.skin_local_pose(mesh, one)), got[2], atol=1e-10)
    # known answers: zero angles give the rest transforms; a translation alone moves
    # every vertex by it, whatever the bases above the roots
    zero = fx.io.ik_poses_to_local(mesh, np.zeros((mesh.num_joints, 3)), tr[0])
    np.testing.assert_allclose(
        np.abs(np.sum(zero.rotations * mesh.rest_rotations, axis=-1)), 1.0, atol=1e-12
    )
    rest = np.asarray(fx.skin_local_pose(mesh, mesh.rest_pose()))
    np.testing.assert_allclose(
        np.asarray(fx.skin_local_pose(mesh, zero)), rest + tr[0], atol=1e-10 * size
    )


def test_mesh_without_poses(meshes, tmp_path):
    mesh = meshes["RiggedSimple"]
    back = fx.io.read_gltf(fx.io.write_gltf(tmp_path / "still.glb", mesh))
    assert back.animations == {}
    np.testing.assert_allclose(
        fx.mesh.rest_vertices(back), fx.mesh.rest_vertices(mesh), atol=1e-6 * _size(mesh)
    )
    # a repeated joint is merged (glTF: one weight per joint and vertex) ...
    w = mesh.skin_weights.copy()
    w[:, 0] /= 2
    split = dataclasses.replace(
        mesh,
        skin_joints=np.concatenate([mesh.skin_joints, mesh.skin_joints[:, :1]], axis=1),
        skin_weights=np.concatenate([w, w[:, :1]], axis=1),
    )
    back = fx.io.read_gltf(fx.io.write_gltf(tmp_path / "split.glb", split))
    assert back.skin_joints.shape == mesh.skin_joints.shape
    np.testing.assert_allclose(_dense_weights(back), _dense_weights(mesh), atol=1e-6)
    # a single pose (J, ·) is a one-key animation
    pose = mesh.sample_animation(0, 1.0)
    back = fx.io.read_gltf(fx.io.write_gltf(tmp_path / "one.glb", mesh, pose, animation="held"))
    np.testing.assert_allclose(
        fx.mesh.animation_vertices(back, "held", [0.0, 5.0]),
        np.repeat(fx.mesh.animation_vertices(mesh, 0, [1.0]), 2, axis=0),
        atol=1e-5 * _size(mesh),
    )


def test_more_than_four_influences(meshes, tmp_path):
    """Five distinct joints per vertex travel as two JOINTS_n/WEIGHTS_n sets."""
    mesh = meshes["CesiumMan"]
    used = np.zeros((mesh.num_vertices, mesh.num_joints), bool)
    np.put_along_axis(used, mesh.skin_joints.astype(np.int64), True, axis=1)
    extra = np.argmin(used, axis=1)[:, None]  # a joint the vertex does not use yet
    five = dataclasses.replace(
        mesh,
        skin_joints=np.concatenate([mesh.skin_joints, extra], axis=1).astype(np.int32),
        skin_weights=np.concatenate([0.8 * mesh.skin_weights, np.full_like(extra, 0.2, float)], 1),
    )
    back = fx.io.read_gltf(fx.io.write_gltf(tmp_path / "five.glb", five))
    assert back.skin_joints.shape == (mesh.num_vertices, 8)
    np.testing.assert_allclose(_dense_weights(back), _dense_weights(five), atol=1e-6)
    pose = mesh.sample_animation(0, np.linspace(0.0, 2.0, 3))  # the weights matter off bind
    want = np.asarray(fx.skin_local_pose(five, pose))
    assert np.abs(want - np.asarray(fx.skin_local_pose(mesh, pose))).max() > 1e-3 * _size(mesh)
    np.testing.assert_allclose(
        np.asarray(fx.skin_local_pose(back, pose)), want, atol=1e-5 * _size(mesh)
    )


def test_refusals_name_the_argument(meshes, tmp_path):
    mesh = meshes["RiggedSimple"]
    nj = mesh.num_joints
    ang, tr = np.zeros((3, nj, 3)), np.zeros((3, 3))
    bad = ang.copy()
    bad[1, 2, 0] = np.nan
    cases = [
        (lambda: fx.io.write_ik_gltf(tmp_path / "a.glb", mesh, bad, tr), "angles holds 1 NaN"),
        (lambda: fx.io.write_ik_gltf(tmp_path / "a.glb", mesh, ang[:, :-1], tr), "angles must"),
        (lambda: fx.io.write_ik_gltf(tmp_path / "a.glb", mesh, ang, tr[:2]), "translation must"),
        (lambda: fx.io.write_ik_gltf(tmp_path / "a.glb", mesh, ang, tr, rate=0), "rate must"),
        (lambda: fx.io.write_ik_gltf(tmp_path / "a.bvh", mesh, ang, tr), "path must end in"),
        (lambda: fx.io.ik_poses_to_local(mesh, ang[0], tr), "translation must"),
    ]
    poses = mesh.sample_animation(0, [0.0, 1.0, 2.0])
    cases += [
        (lambda: fx.io.write_gltf(tmp_path / "a.glb", mesh, poses, [0.0, 2.0, 1.0]), "times"),
        (lambda: fx.io.write_gltf(tmp_path / "a.glb", mesh, poses, [-1.0, 0, 1]), "times"),
        (lambda: fx.io.write_gltf(tmp_path / "a.glb", mesh, poses, [0.0, 1.0]), "times"),
        (lambda: fx.io.write_gltf(tmp_path / "a.glb", mesh, None, [0.0]), "without poses"),
        (lambda: fx.io.write_gltf(tmp_path / "a.glb", mesh, poses[:2]), "poses must be"),
        (
            lambda: fx.io.write_gltf(
                tmp_path / "a.glb", mesh, poses._replace(scales=poses.scales[:, :-1])
            ),
            "poses.scales",
        ),
        (
            lambda: fx.io.write_gltf(
                tmp_path / "a.glb", mesh, poses._replace(rotations=poses.rotations * np.inf)
            ),
            "poses.rotations",
        ),
    ]
    for call, match in cases:
        with pytest.raises(FxspaceError, match=match):
            call()
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_rotation_keys_take_the_short_arc(meshes, tmp_path):
    """Quaternion keys are written sign-continuous (q and -q are one rotation; viewers that
    interpolate components would otherwise swing the long way round)."""
    mesh = meshes["RiggedSimple"]
    t = np.linspace(*mesh.animation_range(0), 6)
    pose = mesh.sample_animation(0, t)
    flip = np.where(np.arange(6) % 2, -1.0, 1.0)[:, None, None]
    path = fx.io.write_gltf(
        tmp_path / "f.glb", mesh, pose._replace(rotations=pose.rotations * flip), t
    )
    back = fx.io.read_gltf(path)
    for ch in back.animations["fxspace"].channels:
        if ch.path == "rotation":
            assert np.all(np.sum(ch.values[1:] * ch.values[:-1], axis=-1) >= 0)
    np.testing.assert_allclose(
        fx.mesh.animation_vertices(back, "fxspace", t),
        fx.mesh.animation_vertices(mesh, 0, t),
        atol=1e-5 * _size(mesh),
    )
