"""Issue 47.1: the joint-speed half of the bound on the clocks. The examples' envelope
(`example_joint_steps`) against forward kinematics written here with scipy, and the
continuous session held inside it by the guard (and not without it: the test can fail)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TOY_NAMES as NAMES
from helpers import TOY_OFFSETS as OFFSETS
from helpers import TOY_PARENTS as PARENTS
from helpers import toy_clips as _clips
from scipy.spatial.transform import Rotation

from fxspace import motion as M

pytestmark = pytest.mark.slow  # two locomotion programs to compile (about a minute)


def _spaces():
    rng = np.random.default_rng(3)
    qL, rL = _clips(rng, 4, 20, 0.3)
    qU, rU = _clips(rng, 2, 16, 0.4)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.8)])
    return M.build_spaces(
        M.stack_examples(list(qL), list(rL), wl), M.stack_examples(list(qU), list(rU), wu),
        np.linspace(0, 15, 20), PARENTS, OFFSETS, mask=M.upper_body_mask(PARENTS, NAMES),
        spine=4, lower_joint=3, lower_dims=(0, 2), lower_time=19.0, upper_joint=-1,
        upper_time=8.0, key=jax.random.PRNGKey(0), n_samples=60, knn_k=4,
    )  # fmt: skip


@pytest.fixture(scope="module")
def sp():
    return _spaces()


def _fk_scipy(root, quats):
    """World positions of one frame: a plain loop over the parents (wxyz quaternions)."""
    J = len(PARENTS)
    R, X = [None] * J, np.zeros((J, 3))
    for j, p in enumerate(PARENTS):
        local = Rotation.from_quat(np.asarray(quats[j], np.float64)[[1, 2, 3, 0]])
        if p < 0:
            R[j], X[j] = local, np.asarray(root, np.float64) + np.asarray(OFFSETS[j])
        else:
            R[j], X[j] = R[p] * local, X[p] + R[p].apply(np.asarray(OFFSETS[j], np.float64))
    return X


def test_example_joint_steps_is_the_fastest_clip_per_joint(sp):
    ref = np.zeros(len(PARENTS))
    for ex in (sp.lower, sp.upper):
        for i in range(ex.warps.shape[0]):
            n = int(ex.lengths[i])
            X = np.stack([_fk_scipy(ex.root[i, t], ex.rotations[i, t]) for t in range(n)])
            ref = np.maximum(ref, np.linalg.norm(np.diff(X, axis=0), axis=-1).max(0))
    got = np.asarray(M.example_joint_steps(sp.lower, sp.upper, PARENTS, OFFSETS))
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(np.asarray(sp.joint_steps), ref, rtol=1e-4, atol=1e-6)


def _steps(sp, alpha, F=60):
    up = jnp.tile(jnp.asarray([0.0, 1.0]), (F, 1))  # the faster upper example
    low = jnp.tile(sp.lower_params[2], (F, 1))  # the slowest lower example (0.8)
    _, poses = M.locomotion(sp, M.init_locomotion(sp, sp.lower_params[2]), up, low,
                            jnp.full((F,), alpha))  # fmt: skip
    X = M.world_positions(PARENTS, OFFSETS, poses)
    return np.linalg.norm(np.diff(X, axis=0), axis=-1) / np.asarray(sp.joint_steps)


def test_guard_keeps_every_joint_inside_the_examples(sp):
    # the toy clips' noisy frames make their envelope loose; a tighter one (an input like
    # any other) puts the rushed walk of α = 0 outside it
    tight = dataclasses.replace(sp, joint_steps=0.4 * sp.joint_steps)
    guarded = _steps(tight, 0.0)
    free = _steps(dataclasses.replace(tight, max_clock_rate=float("inf")), 0.0)
    print(f"fastest joint / fastest clip's same joint: guarded {guarded.max():.3f}, "
          f"eqs. 2-3 as printed {free.max():.3f}")  # fmt: skip
    assert free.max() > 1.05  # as printed, the walk outruns every capture here ...
    assert guarded.max() <= 1.0  # ... the default bound never does
    # and it only holds back: the guarded walk still moves on
    assert guarded.sum() > 0.5 * free.sum()
