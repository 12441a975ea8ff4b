"""Forward kinematics: hand-computed chains, jit/vmap/grad, and AMC vs BVH of CMU 131_01."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import check_grad

import fxspace as fx
from fxspace.io import Motion
from fxspace.motion import euler_to_quat, fk_arrays

IDENT = [1.0, 0.0, 0.0, 0.0]


def _chain(rot_deg_z, root=(1.0, 2.0, 3.0)):
    """root → a (offset 0) → b (offset (1,0,0)) → tip (offset (0,2,0)); rotations about z."""
    q = euler_to_quat(np.asarray(rot_deg_z, dtype=np.float64)[..., None], "Z")
    T = q.shape[0]
    return Motion(
        names=("root", "a", "b", "tip"),
        parents=(-1, 0, 1, 2),
        offsets=jnp.asarray([[0.0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 2, 0]]),
        root_translation=jnp.broadcast_to(jnp.asarray(root), (T, 3)),
        rotations=jnp.asarray(q),
        rate=30.0,
        channels=((), (), (), ()),
    )


def test_hand_computed_chain():
    # frame 0: no rotation; frame 1: root +90° about z; frame 2: a +90°, b −90°
    m = _chain([[0, 0, 0, 0], [90, 0, 0, 0], [0, 90, -90, 0]])
    X = np.asarray(fx.forward_kinematics(m))
    r = np.asarray([1.0, 2.0, 3.0])
    np.testing.assert_allclose(
        X[0], r + np.asarray([[0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 2, 0]]), atol=1e-12
    )
    # +90° about z maps x→y, y→−x
    np.testing.assert_allclose(
        X[1], r + np.asarray([[0, 0, 0], [0, 0, 0], [0, 1, 0], [-2, 1, 0]]), atol=1e-12
    )
    # b sits at a's rotated offset (0,1,0); b's −90° cancels a's +90° for the tip
    np.testing.assert_allclose(X[2, 3], r + [0.0, 3.0, 0.0], atol=1e-12)


def test_jit_vmap_grad(rng):
    T = 5
    ang = rng.uniform(-90, 90, size=(T, 4))
    m = _chain(ang)
    eager = fx.forward_kinematics(m)
    np.testing.assert_allclose(jax.jit(fx.forward_kinematics)(m), eager, atol=1e-12)
    # vmap over clips stacked on a leading axis
    m2 = _chain(rng.uniform(-90, 90, size=(T, 4)))
    stacked = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), m, m2)
    batched = jax.vmap(fx.forward_kinematics)(stacked)
    np.testing.assert_allclose(batched[0], eager, atol=1e-12)
    np.testing.assert_allclose(batched[1], fx.forward_kinematics(m2), atol=1e-12)

    # gradient of the tip height with respect to the joint angles (radians)
    def f(a):
        q = euler_to_quat(a[:, None], "Z", degrees=False)
        X, _ = fk_arrays(m.parents, m.offsets, jnp.zeros(3), q)
        return X[3, 1] + 0.3 * X[2, 0]

    check_grad(jax.jit(f), jnp.asarray(rng.uniform(-1, 1, size=4)), rng)


def test_validation():
    m = _chain([[0, 0, 0, 0]])
    with pytest.raises(ValueError, match="parents"):
        fx.forward_kinematics(dataclasses.replace(m, parents=(-1, 2, 0, 1)))
    with pytest.raises(ValueError, match="rotations must have shape"):
        fx.forward_kinematics(dataclasses.replace(m, rotations=m.rotations[:, :3]))


# BVH joint → AMC joint (joints sit at bone starts in both); see docs in fxspace.io._asfamc.
EXACT = {
    "Hips": "root",
    "LHipJoint": "lhipjoint",
    "LeftHip": "lfemur",
    "LeftKnee": "ltibia",
    "LeftAnkle": "lfoot",
    "LeftToe": "ltoes",
    "LeftToe_end": "ltoes_end",
    "RHipJoint": "rhipjoint",
    "RightHip": "rfemur",
    "RightKnee": "rtibia",
    "RightAnkle": "rfoot",
    "RightToe": "rtoes",
    "RightToe_end": "rtoes_end",
    "lowerback": "lowerback",
    "Chest": "upperback",
    "Chest2": "thorax",
}
# above the thorax the public BVH conversion drops the thorax bone's length: its joints are
# the AMC ones moved back by the thorax bone vector (rotated with the thorax)
SHIFTED = {
    "Neck": "upperneck",
    "Head": "head",
    "Head_end": "head_end",
    "LeftShoulder": "lhumerus",
    "LeftElbow": "lradius",
    "LeftWrist": "lwrist",
    "RightShoulder": "rhumerus",
    "RightElbow": "rradius",
    "RightWrist": "rwrist",
}


def test_amc_vs_bvh_same_take(data_dir):
    body = data_dir / "body"
    unit = 0.0254 / 0.45  # ASF ":units length 0.45" → 1 unit = 1/0.45 inch; the BVH uses it too
    a = fx.io.read_amc(body / "cmu" / "131" / "131.asf", body / "cmu" / "131" / "131_01.amc.gz")
    b = fx.io.read_bvh(body / "bvh" / "131_01.bvh.gz", scale=unit)
    assert a.num_frames == b.num_frames == 994
    sl = slice(None, None, 7)
    a, b = a.frames(sl), b.frames(sl)
    Xa, Ra = fk_arrays(a.parents, a.offsets, a.root_translation, a.rotations)
    Xb = fx.forward_kinematics(b)
    Xa, Ra, Xb = np.asarray(Xa), np.asarray(Ra), np.asarray(Xb)
    # same axes (Y up), same units after the conversion: agreement to the BVH's 4 decimals
    for bn, an in EXACT.items():
        err = np.abs(Xa[:, a.index(an)] - Xb[:, b.index(bn)]).max()
        assert err < 2e-5, (bn, an, err)  # 0.02 mm
    thorax = np.einsum(
        "tab,b->ta", Ra[:, a.index("thorax")], np.asarray(a.offsets[a.index("lowerneck")])
    )
    for bn, an in SHIFTED.items():
        err = np.abs(Xa[:, a.index(an)] - thorax - Xb[:, b.index(bn)]).max()
        assert err < 2e-5, (bn, an, err)
    # and without the correction the upper joints are off by the thorax length (~11 cm)
    off = np.linalg.norm(Xa[:, a.index("lhumerus")] - Xb[:, b.index("LeftShoulder")], axis=1)
    np.testing.assert_allclose(off, 1.98337 * unit, rtol=1e-3)
