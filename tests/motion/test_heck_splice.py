"""Heck, Kovar & Gleicher's splice (spatial alignment, then posture transfer) as Ha & Han §3
use it: checked against scipy's Kabsch (`Rotation.align_vectors`) and on poses with known
answers; jit / vmap / grad; the Fig. 2 problem it causes and the §3.2 re-placement."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TOY_NAMES, TOY_PARENTS
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.motion import fk_arrays, heck_splice, torso_joints, upper_body_mask
from fxspace.rotations import euler_to_quat

# root → spine → chest → (neck → head, lclavicle → lshoulder → lelbow, rclavicle → ...)
# plus two legs: a CMU-like torso that branches at the chest
NAMES = (
    "root", "spine", "chest", "neck", "head", "lclav", "lshoulder", "lelbow",
    "rclav", "rshoulder", "relbow", "lhip", "lknee", "rhip", "rknee",
)  # fmt: skip
PARENTS = (-1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 0, 13)
OFFSETS = np.asarray(
    [[0, 1.0, 0], [0, 0.1, 0], [0, 0.25, 0], [0, 0.2, 0], [0, 0.15, 0.02], [0.05, 0.15, 0],
     [0.15, 0, 0], [0.3, 0, 0], [-0.05, 0.15, 0], [-0.15, 0, 0], [-0.3, 0, 0],
     [0.1, -0.05, 0], [0, -0.45, 0], [-0.1, -0.05, 0], [0, -0.45, 0]], float,
)  # fmt: skip
MASK = upper_body_mask(PARENTS, NAMES, "spine")
TORSO = torso_joints(PARENTS, MASK, 1)


def _pose(rng, amp=0.3):
    aa = rng.standard_normal((len(PARENTS), 3)) * amp
    return jnp.asarray(Rotation.from_rotvec(aa).as_quat(scalar_first=True))


def test_torso_joints_are_spine_neck_and_shoulders():
    got = [NAMES[j] for j in TORSO]
    assert got == ["spine", "chest", "neck", "head", "lclav", "lshoulder", "rclav", "rshoulder"]
    # no branch of three: every upper-body joint
    toy_mask = upper_body_mask(TOY_PARENTS, TOY_NAMES)
    assert torso_joints(TOY_PARENTS, toy_mask, 4) == (4, 5, 6, 7)
    with pytest.raises(ValueError, match="mask"):
        torso_joints(PARENTS, np.zeros(len(PARENTS), bool), 1)


def test_same_frame_gives_the_frame_back(rng):
    q = _pose(rng)
    for pt in (0.0, 0.5, 1.0):
        out = heck_splice(q, q, PARENTS, OFFSETS, MASK, 1, TORSO, pt)
        np.testing.assert_allclose(out, q, atol=1e-9)


def test_spatial_alignment_is_kabsch_on_the_torso(rng):
    qL, qU = _pose(rng), _pose(rng)
    out = heck_splice(qL, qU, PARENTS, OFFSETS, MASK, 1, TORSO, 0.0)
    z = np.zeros(3)
    XL, RL = fk_arrays(PARENTS, OFFSETS, z, qL)
    XU, RU = fk_arrays(PARENTS, OFFSETS, z, qU)
    XS, RS = fk_arrays(PARENTS, OFFSETS, z, out)
    idx = list(TORSO)
    src = (np.asarray(XU)[idx] - np.asarray(XU)[1]) @ np.asarray(RU)[1]
    dst = np.asarray(XL)[idx] - np.asarray(XL)[1]
    ref, _ = Rotation.align_vectors(dst, src)  # scipy's Kabsch, independent of Horn's quaternion
    np.testing.assert_allclose(np.asarray(RS)[1], ref.as_matrix(), atol=1e-9)
    # the lower body and the arms' local rotations are untouched
    np.testing.assert_allclose(out[~np.asarray(MASK)], qL[~np.asarray(MASK)])
    np.testing.assert_allclose(out[2:11], qU[2:11])


def test_posture_transfer_gives_back_the_actions_lean():
    # the action leans 25° forward; the locomotion walks upright, turned 40° (heading)
    q = jnp.tile(jnp.asarray([1.0, 0.0, 0.0, 0.0]), (len(PARENTS), 1))
    qU = q.at[1].set(euler_to_quat(jnp.asarray([25.0]), "X"))
    qL = q.at[0].set(euler_to_quat(jnp.asarray([40.0]), "Y"))
    z = np.zeros(3)
    _, RU = fk_arrays(PARENTS, OFFSETS, z, qU)
    up_u = np.asarray(RU)[1] @ np.asarray([0.0, 1.0, 0.0])
    yaw = Rotation.from_euler("y", 40, degrees=True).as_matrix()
    for pt, lean in ((0.0, 0.0), (0.5, 12.5), (1.0, 25.0)):
        out = heck_splice(qL, qU, PARENTS, OFFSETS, MASK, 1, TORSO, pt)
        _, RS = fk_arrays(PARENTS, OFFSETS, z, out)
        up = np.asarray(RS)[1] @ np.asarray([0.0, 1.0, 0.0])
        assert np.degrees(np.arccos(np.clip(up[1], -1, 1))) == pytest.approx(lean, abs=1e-6)
        if pt == 1.0:  # the action's lean, in the locomotion's heading
            np.testing.assert_allclose(up, yaw @ up_u, atol=1e-9)


def test_jit_vmap_grad(rng):
    qL, qU = _pose(rng), _pose(rng)
    f = jax.jit(lambda a, b, p: heck_splice(a, b, PARENTS, OFFSETS, MASK, 1, TORSO, p))
    np.testing.assert_allclose(f(qL, qU, 0.7), heck_splice(qL, qU, PARENTS, OFFSETS, MASK, 1,
                                                            TORSO, 0.7), atol=1e-12)  # fmt: skip
    batch = jax.vmap(f, in_axes=(None, 0, None))(qL, jnp.stack([qU, qL]), 0.7)
    np.testing.assert_allclose(batch[1], qL, atol=1e-9)
    g = jax.grad(lambda p: jnp.sum(f(qL, qU, p)[1] * jnp.asarray([0.0, 1.0, 2.0, 3.0])))(0.4)
    eps = 1e-6
    fd = (
        jnp.sum(f(qL, qU, 0.4 + eps)[1] * jnp.asarray([0.0, 1.0, 2.0, 3.0]))
        - jnp.sum(f(qL, qU, 0.4 - eps)[1] * jnp.asarray([0.0, 1.0, 2.0, 3.0]))
    ) / (2 * eps)
    assert float(g) == pytest.approx(float(fd), rel=1e-5, abs=1e-8)


def test_bad_input_names_the_argument(rng):
    q = _pose(rng)
    with pytest.raises(ValueError, match="torso"):
        heck_splice(q, q, PARENTS, OFFSETS, MASK, 1, (1, 2), 1.0)
    with pytest.raises(ValueError, match="posture_transfer"):
        heck_splice(q, q, PARENTS, OFFSETS, MASK, 1, TORSO, 1.5)
    with pytest.raises(ValueError, match="lower_q"):
        heck_splice(q[:-1], q, PARENTS, OFFSETS, MASK, 1, TORSO, 1.0)
    nan = heck_splice(q.at[0].set(jnp.nan), q, PARENTS, OFFSETS, MASK, 1, TORSO, 1.0)
    assert bool(jnp.all(jnp.isnan(nan[1])))  # missing data stays missing


def _clips(rng, E, T, amp):
    """E clips of T frames on the CMU-like skeleton: every joint swings sinusoidally."""
    t = np.arange(T)[None, :, None, None]
    ax = rng.standard_normal((E, 1, len(PARENTS), 3)) * amp
    ph = rng.uniform(0, 2 * np.pi, (E, 1, len(PARENTS), 1))
    q = Rotation.from_rotvec((ax * np.sin(2 * np.pi * t / T + ph)).reshape(-1, 3))
    q = q.as_quat(scalar_first=True).reshape(E, T, len(PARENTS), 4)
    root = np.zeros((E, T, 3))
    root[..., 2] = np.linspace(0, 1, T)[None] * rng.uniform(0.5, 1.5, (E, 1))
    return q, root


def _spaces(rng):
    qL, rL = _clips(rng, 4, 20, 0.3)
    qU, rU = _clips(rng, 5, 16, 0.3)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.7, 0.9, 0.8, 1.0)])
    exL = fx.motion.stack_examples(list(qL), list(rL), wl)
    exU = fx.motion.stack_examples(list(qU), list(rU), wu)
    return exL, exU


def test_fig2_problem_and_replacement():
    # with Heck's splice a new lower body moves every upper sample differently (Fig. 2):
    # re-placement is no longer exact, but far closer to exact re-sampling than stale samples
    exL, exU = _spaces(np.random.default_rng(1))
    kw = dict(
        mask=MASK, spine=1, lower_joint=12, lower_dims=(0, 2), lower_time=19.0, upper_joint=7,
        upper_time=8.0, key=jax.random.PRNGKey(0), knn_k=4, k_replace=8, posture_transfer=1.0,
    )  # fmt: skip
    sp = fx.motion.build_spaces(exL, exU, np.linspace(0, 15, 20), PARENTS, OFFSETS,
                                n_samples=80, **kw)  # fmt: skip
    assert sp.splice == "heck"
    w_new = jnp.asarray([0.1, 0.2, 0.6, 0.1])
    exact = fx.motion.exact_upper_params(sp, w_new)
    e_repl = np.linalg.norm(np.asarray(fx.motion.replace_samples(sp, w_new) - exact), axis=1)
    e_stale = np.linalg.norm(np.asarray(sp.upper_params - exact), axis=1)
    assert e_repl.mean() > 1e-4  # not a rigid change any more
    # §3.2's rotation about the root (the default): measured 19 mm vs 75 mm stale
    assert e_repl.mean() < 0.35 * e_stale.mean()
    # the heading-relative copy at full posture transfer moves the samples rigidly: Horn's
    # rigid option is exact there
    sh = dataclasses.replace(sp, splice="heading", replace="rigid")
    sh = dataclasses.replace(sh, upper_params=fx.motion.exact_upper_params(sh, sh.lower_w0))
    np.testing.assert_allclose(
        fx.motion.replace_samples(sh, w_new), fx.motion.exact_upper_params(sh, w_new), atol=2e-5
    )
    with pytest.raises(ValueError, match="splice"):
        fx.motion.build_spaces(exL, exU, np.linspace(0, 15, 20), PARENTS, OFFSETS,
                               n_samples=10, splice="naive", **kw)  # fmt: skip
    # §3.2 as printed (the default): one rotation about the root, so every re-placed
    # sample keeps its distance from the root (the root stays where it is); the full
    # rigid transform (an option) also follows a shift of the samples
    assert sp.replace == "rotation"
    repl = np.asarray(fx.motion.replace_samples(sp, w_new))
    before = np.linalg.norm(np.asarray(sp.upper_params), axis=1)
    np.testing.assert_allclose(np.linalg.norm(repl, axis=1), before, rtol=1e-6)
    rigid = dataclasses.replace(sp, replace="rigid")
    e_rigid = np.linalg.norm(np.asarray(fx.motion.replace_samples(rigid, w_new) - exact), axis=1)
    assert e_rigid.mean() < 0.25 * e_stale.mean()  # measured: 14.5 mm
    with pytest.raises(ValueError, match="replace"):
        fx.motion.build_spaces(exL, exU, np.linspace(0, 15, 20), PARENTS, OFFSETS,
                               n_samples=10, replace="shift", **kw)  # fmt: skip
