"""glTF reader: hand-built files with known answers, and the three real meshes."""

from __future__ import annotations

import numpy as np
import pygltflib as G
import pytest
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial.transform import Rotation, Slerp

import fxspace as fx
from fxspace.errors import CorruptFileError, FxspaceError

_CTYPE = {
    np.float32: G.FLOAT,
    np.uint16: G.UNSIGNED_SHORT,
    np.uint32: G.UNSIGNED_INT,
    np.uint8: G.UNSIGNED_BYTE,
}
_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}

ROT_T = np.array([0.0, 1.0, 2.0], dtype=np.float32)
ROT_Q = (
    Rotation.from_euler("z", [[0.0], [60.0], [150.0]], degrees=True).as_quat().astype(np.float32)
)
STEP_T = np.array([0.0, 1.5], dtype=np.float32)
STEP_V = np.array([[0, 0, 0], [0.5, 0.0, 0.0]], dtype=np.float32)
CUB_T = np.array([0.0, 2.0], dtype=np.float32)
# per key: in-tangent, value, out-tangent
CUB_V = np.array(
    [[[0, 0, 0], [1, 1, 1], [0.5, 0, 0]], [[0, 1, 0], [2, 1, 1], [0, 0, 0]]], dtype=np.float32
)


def _quad(y0: float, y1: float) -> tuple[np.ndarray, np.ndarray]:
    """A two-triangle quad in the plane z = 0 between heights y0 and y1, facing +z."""
    v = np.array([[-0.5, y0, 0], [0.5, y0, 0], [0.5, y1, 0], [-0.5, y1, 0]], dtype=np.float32)
    return v, np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)


def build_gltf(path, *, two_primitives=True, mode=4, two_meshes=False, truncate=0):
    """Two-joint chain (skin order child-first), one or two primitives, three channels."""
    blob = bytearray()
    views, accs = [], []

    def add(arr):
        arr = np.ascontiguousarray(arr)
        while len(blob) % 4:
            blob.append(0)
        views.append(G.BufferView(buffer=0, byteOffset=len(blob), byteLength=arr.nbytes))
        blob.extend(arr.tobytes())
        width = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
        accs.append(
            G.Accessor(
                bufferView=len(views) - 1,
                componentType=_CTYPE[arr.dtype.type],
                count=arr.shape[0],
                type=_TYPE[width],
            )
        )
        return len(accs) - 1

    prims = []
    parts = [_quad(0.0, 1.0), _quad(1.0, 2.0)] if two_primitives else [_quad(0.0, 2.0)]
    for v, idx in parts:
        # skin joint 0 = the child (node 1), skin joint 1 = the root (node 0)
        jw = np.where(v[:, 1] > 1.0, 0.0, 1.0).astype(np.float32)  # weight on the root
        joints = np.tile(np.array([0, 1, 0, 0], dtype=np.uint8), (4, 1))
        weights = np.stack([1 - jw, jw, 0 * jw, 0 * jw], axis=1).astype(np.float32)
        prims.append(
            G.Primitive(
                attributes=G.Attributes(
                    POSITION=add(v), JOINTS_0=add(joints), WEIGHTS_0=add(weights)
                ),
                indices=add(idx),
                mode=mode,
            )
        )
    # inverse bind matrices, skin order [child, root]
    ibm = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
    ibm[0, 1, 3] = -1.0  # child sits at y = 1
    ibm_acc = add(ibm.transpose(0, 2, 1).reshape(2, 16))
    nodes = [
        G.Node(name="root", children=[1], translation=[0.0, 0.0, 0.0]),
        G.Node(name="child", translation=[0.0, 1.0, 0.0]),
        G.Node(name="body", mesh=0, skin=0),
        G.Node(name="Armature", children=[0, 2], translation=[0.0, 0.0, 0.0]),
    ]
    meshes = [G.Mesh(name="m", primitives=prims)]
    scene_nodes = [3]
    if two_meshes:
        nodes.append(G.Node(name="body2", mesh=1, skin=0))
        meshes.append(G.Mesh(name="m2", primitives=prims[:1]))
        scene_nodes.append(4)
    samplers = [
        G.AnimationSampler(input=add(ROT_T), output=add(ROT_Q), interpolation="LINEAR"),
        G.AnimationSampler(input=add(STEP_T), output=add(STEP_V), interpolation="STEP"),
        G.AnimationSampler(
            input=add(CUB_T), output=add(CUB_V.reshape(-1, 3)), interpolation="CUBICSPLINE"
        ),
    ]
    channels = [
        G.AnimationChannel(sampler=0, target=G.AnimationChannelTarget(node=1, path="rotation")),
        G.AnimationChannel(sampler=1, target=G.AnimationChannelTarget(node=0, path="translation")),
        G.AnimationChannel(sampler=2, target=G.AnimationChannelTarget(node=1, path="scale")),
    ]
    g = G.GLTF2(
        scene=0,
        scenes=[G.Scene(nodes=scene_nodes)],
        nodes=nodes,
        meshes=meshes,
        skins=[G.Skin(joints=[1, 0], inverseBindMatrices=ibm_acc)],
        animations=[G.Animation(name="wave", samplers=samplers, channels=channels)],
        accessors=accs,
        bufferViews=views,
        buffers=[G.Buffer(byteLength=len(blob))],
    )
    data = bytes(blob)
    if truncate:
        data = data[:-truncate]
    g.set_binary_blob(data)
    g.save_binary(str(path))
    return path


@pytest.fixture
def toy(tmp_path):
    return fx.io.read_gltf(build_gltf(tmp_path / "toy.glb"))


def test_structure_and_reordering(toy):
    # the skin lists the child first; the reader puts parents first and remaps JOINTS_0
    assert toy.joint_names == ("root", "child")
    np.testing.assert_array_equal(toy.parents, [-1, 0])
    assert toy.joint_nodes == (0, 1)
    assert toy.vertices.shape == (8, 3) and toy.faces.shape == (4, 3)
    # second primitive's indices are offset by the first primitive's 4 vertices
    assert toy.faces.max() == 7 and toy.faces[2:].min() == 4
    top = toy.vertices[:, 1] > 1.0
    np.testing.assert_array_equal(toy.skin_joints[top, 0], 1)  # child, now index 1
    np.testing.assert_allclose(toy.skin_weights.sum(axis=1), 1.0)
    np.testing.assert_allclose(toy.inverse_bind[1][1, 3], -1.0)  # the child's IBM moved
    np.testing.assert_allclose(fx.mesh.rest_vertices(toy), toy.vertices, atol=1e-6)


def test_animation_sampling_matches_keyframes(toy):
    assert toy.animation_names == ("wave",)
    assert toy.animation_range("wave") == (0.0, 2.0)
    # at the keys: the key values
    p = toy.sample_animation("wave", ROT_T)
    np.testing.assert_allclose(np.abs(np.sum(p.rotations[:, 1] * ROT_Q, axis=1)), 1.0, atol=1e-6)
    # between keys: spherical linear interpolation (scipy's Slerp as the reference)
    t = np.array([0.25, 0.5, 1.3, 1.9])
    ref = Slerp(ROT_T, Rotation.from_quat(ROT_Q))(t)
    got = Rotation.from_quat(toy.sample_animation("wave", t).rotations[:, 1])
    np.testing.assert_allclose((ref.inv() * got).magnitude(), 0.0, atol=1e-6)
    # STEP: previous key until the next key time
    tr = toy.sample_animation("wave", np.array([0.0, 1.49, 1.5, 3.0])).translations[:, 0]
    np.testing.assert_allclose(tr, STEP_V[[0, 0, 1, 1]], atol=1e-7)
    # CUBICSPLINE: Hermite with tangents scaled by the key interval (scipy reference)
    t = np.array([0.0, 0.3, 1.0, 1.7, 2.0])
    spl = CubicHermiteSpline(CUB_T, CUB_V[:, 1], np.stack([CUB_V[0, 2], CUB_V[1, 0]]))
    np.testing.assert_allclose(toy.sample_animation("wave", t).scales[:, 1], spl(t), atol=1e-6)
    # clamped outside the range; joints without channels keep their rest values
    np.testing.assert_allclose(toy.sample_animation("wave", -1.0).rotations[1], ROT_Q[0], atol=1e-7)
    np.testing.assert_allclose(toy.sample_animation(0, 0.5).scales[0], [1, 1, 1])


def test_animation_vertices_deform_as_specified(toy):
    # at t = 1: the child turns 60° about z (scale 1.5-ish from the spline); vertices
    # weighted fully to the child rotate about the child's origin (0, 1, 0)
    t = np.array([1.0])
    pose = toy.sample_animation("wave", t)
    v = fx.mesh.animation_vertices(toy, "wave", t)[0]
    r = Rotation.from_quat(pose.rotations[0, 1]).as_matrix()
    s = pose.scales[0, 1]
    top = toy.vertices[:, 1] > 1.0
    expect = (r @ (s * (toy.vertices[top] - [0, 1, 0])).T).T + [0, 1, 0]
    np.testing.assert_allclose(v[top], expect, atol=1e-6)
    bottom = toy.vertices[:, 1] < 1.0 - 1e-6
    np.testing.assert_allclose(v[bottom], toy.vertices[bottom], atol=1e-6)
    assert fx.mesh.animation_vertices(toy, "wave", np.linspace(0, 2, 7)).shape == (7, 8, 3)


def test_refusals(tmp_path):
    with pytest.raises(FxspaceError, match="TRIANGLES"):
        fx.io.read_gltf(build_gltf(tmp_path / "lines.glb", mode=1))
    with pytest.raises(FxspaceError, match="mesh="):
        fx.io.read_gltf(build_gltf(tmp_path / "two.glb", two_meshes=True))
    assert fx.io.read_gltf(build_gltf(tmp_path / "two2.glb", two_meshes=True), mesh="body2")
    with pytest.raises(CorruptFileError):
        fx.io.read_gltf(build_gltf(tmp_path / "cut.glb", truncate=200))
    with pytest.raises(FxspaceError, match="does not exist"):
        fx.io.read_gltf(tmp_path / "missing.glb")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF not really")
    with pytest.raises(CorruptFileError):
        fx.io.read_gltf(bad)
    m = fx.io.read_gltf(build_gltf(tmp_path / "ok.glb", two_primitives=False))
    with pytest.raises(FxspaceError, match="choose one of"):
        m.sample_animation("nope", 0.0)


@pytest.mark.parametrize(
    "name, joints, verts, anims",
    [
        ("Fox", 24, 1728, ("Survey", "Walk", "Run")),
        ("CesiumMan", 19, 3273, ("Anim_0",)),
        ("RiggedSimple", 4, 960, ("Anim_0_Armature",)),
    ],
)
def test_real_meshes(data_dir, name, joints, verts, anims):
    m = fx.io.read_gltf(data_dir / "mesh" / f"{name}.glb")
    assert m.num_joints == joints and m.num_vertices == verts and m.animation_names == anims
    assert np.all(m.parents < np.arange(joints))
    # the rest pose of these files is their bind pose
    scale = np.ptp(m.vertices, axis=0).max()
    np.testing.assert_allclose(fx.mesh.rest_vertices(m), m.vertices, atol=1e-6 * scale)
    # sampling at the keyframe times returns the keyframes
    ch = next(c for c in m.animations[anims[0]].channels if c.path == "rotation")
    got = m.sample_animation(anims[0], ch.times).rotations[:, ch.joint]
    np.testing.assert_allclose(np.abs(np.sum(got * ch.values, axis=1)), 1.0, atol=1e-6)
    # the animation moves the mesh and keeps it bounded (no exploded vertices)
    v = fx.mesh.animation_vertices(m, anims[0], np.linspace(*m.animation_range(anims[0]), 4))
    assert np.isfinite(v).all() and np.abs(v - m.vertices).max() > 1e-3 * scale
    assert np.ptp(v, axis=1).max() < 3 * scale


def test_json_gltf_with_embedded_buffer_reads_the_same(tmp_path, toy):
    g = G.GLTF2().load(str(build_gltf(tmp_path / "a.glb")))
    g.convert_buffers(G.BufferFormat.DATAURI)
    g.save_json(str(tmp_path / "a.gltf"))
    m = fx.io.read_gltf(tmp_path / "a.gltf")
    np.testing.assert_array_equal(m.vertices, toy.vertices)
    np.testing.assert_array_equal(m.faces, toy.faces)
    t = np.linspace(0, 2, 5)
    np.testing.assert_allclose(
        fx.mesh.animation_vertices(m, "wave", t), fx.mesh.animation_vertices(toy, "wave", t)
    )


def test_ik_poses_written_as_bvh_round_trip(data_dir, tmp_path):
    """IK poses → BVH → read_bvh → forward kinematics gives the IK joint origins."""
    import jax.numpy as jnp

    mesh = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    rng = np.random.default_rng(0)
    ang = rng.normal(0, 0.3, (3, mesh.num_joints, 3))
    tr = rng.normal(0, 0.1, (3, 3))
    path = fx.io.write_ik_bvh(tmp_path / "ik.bvh", mesh, ang, tr, rate=24.0)
    mot = fx.io.read_bvh(path)
    assert mot.num_frames == 3 and mot.names == mesh.joint_names
    assert abs(mot.rate - 24.0) < 1e-4  # BVH stores the frame time in text
    model = fx.ik_model(mesh, fx.place_markers(mesh.vertices, mesh.faces, 2, seed=0))
    origins = np.stack(
        [
            np.asarray(fx.ik_forward(model, fx.Pose(jnp.asarray(a), jnp.asarray(t))).origins)
            for a, t in zip(ang, tr, strict=True)
        ]
    )
    np.testing.assert_allclose(np.asarray(fx.forward_kinematics(mot)), origins, atol=1e-5)
    with pytest.raises(FxspaceError, match="finite"):
        fx.io.write_ik_bvh(tmp_path / "bad.bvh", mesh, ang * np.nan, tr)
