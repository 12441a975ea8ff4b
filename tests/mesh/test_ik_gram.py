"""Mesh IK: the Levenberg–Marquardt kernel (`gram_normal_equations`, markers minor, one
product for the Gram matrix) and the LM solve's own bookkeeping (no conditional, the
objective at the returned pose)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mesh_toys import _flat, both_views, branching_mesh, random_pose

import fxspace as fx
from fxspace.mesh._ik_gradients import (
    gram_normal_equations,
    lever_arms,
    marker_normal_equations,
)

_slow = pytest.mark.slow


@pytest.fixture(scope="module")
def toy():
    m = branching_mesh(0, uniform_scale=1.7)
    ms = both_views(m, 20, 20)
    return m, fx.ik_model(m, ms)


def _check_against_the_dense_form(model, pose, targets, weights):
    fw = fx.ik_forward(model, pose)
    r = fw.markers - targets
    p = lever_arms(model, fw)
    g_ref, h_ref = marker_normal_equations(fw, p, r, weights)
    w = np.ones(targets.shape[0]) if weights is None else np.asarray(weights)
    obj_ref = float(np.sum(w[:, None] * np.asarray(r) ** 2))
    obj, g, h, parts = jax.jit(gram_normal_equations)(model, pose, targets, weights)
    np.testing.assert_allclose(float(obj), obj_ref, rtol=1e-12)
    np.testing.assert_allclose(g, g_ref, atol=1e-11 * np.abs(g_ref).max())
    np.testing.assert_allclose(h, h_ref, atol=1e-11 * np.abs(h_ref).max())
    np.testing.assert_allclose(h, np.asarray(h).T, atol=1e-12 * np.abs(h_ref).max())
    np.testing.assert_allclose(parts.markers, fw.markers, atol=1e-12)
    np.testing.assert_allclose(jnp.transpose(parts.lever_arms, (2, 0, 1)), p, atol=1e-12)
    np.testing.assert_allclose(parts.axes, fw.axes, atol=1e-13)


@pytest.mark.parametrize(
    "parents",
    [
        pytest.param(None, id="toy6"),
        pytest.param([-1, 0, 1, 2], id="chain4", marks=_slow),
        pytest.param([-1, 0, 1, 2, 3, 4, 5, 6, 7, 1, 9, -1, 11, 12], id="forest14", marks=_slow),
    ],
)
def test_gram_normal_equations_match_the_dense_form(parents, rng):
    """Against `marker_normal_equations` (lever arms markers-major), with and without
    marker weights; 6, 4 and 14 joints pad the Gram rows (3J + 4) by 2, 0 and 2."""
    m = branching_mesh(0, uniform_scale=1.7, parents=parents)
    model = fx.ik_model(m, both_views(m, 20, 20))
    for weights in (None, jnp.asarray(rng.uniform(0.0, 2.0, model.marker_joints.shape[0]))):
        pose = random_pose(rng, m.num_joints)
        targets = fx.ik_markers(model, random_pose(rng, m.num_joints))
        _check_against_the_dense_form(model, pose, targets, weights)


@pytest.mark.slow
def test_gram_normal_equations_on_cesium_man(data_dir, rng):
    """The shipped human at the benchmark's 120 markers (61 Gram rows, padded to 64)."""
    path = data_dir / "mesh" / "CesiumMan.glb"
    if not path.exists():
        pytest.skip(f"{path} not found (set FXSPACE_DATA to the data root)")
    m = fx.io.read_gltf(path)
    model = fx.ik_model(m, fx.place_markers(m.vertices, m.faces, 120, seed=0))
    pose = random_pose(rng, m.num_joints, 0.3, 0.05)
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints, 0.3, 0.05))
    _check_against_the_dense_form(model, pose, targets, None)


@pytest.mark.slow
def test_lm_objective_is_the_objective_at_the_returned_pose(toy, rng):
    """Unconstrained LM reports its own last objective (no second forward pass): equal to
    E at the returned pose, the residual its RMS; NaN for non-finite input."""
    m, model = toy
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints, 0.3, 0.05))
    targets = targets + jnp.asarray(rng.normal(0, 0.02, targets.shape))
    for init in (fx.rest_pose(m), random_pose(rng, m.num_joints, 0.2, 0.05)):
        for solver in (fx.mesh.LevenbergMarquardt(rtol=1e-3), fx.mesh.LevenbergMarquardt()):
            res = fx.solve_ik(model, targets, init, solver=solver)
            e = float(fx.ik_objective(model, res.pose, targets))
            np.testing.assert_allclose(float(res.objective), e, rtol=1e-10)
            np.testing.assert_allclose(float(res.stats["objective"]), e, rtol=1e-10)
            np.testing.assert_allclose(
                float(res.residual), np.sqrt(e / targets.shape[0]), rtol=1e-10
            )
    # a solve that takes no step reports the objective at the initial pose
    one = fx.solve_ik(model, targets, solver=fx.mesh.LevenbergMarquardt(atol=1.0))
    assert int(one.num_steps) == 0 and bool(one.converged)
    e0 = float(fx.ik_objective(model, fx.rest_pose(m), targets))
    np.testing.assert_allclose(float(one.objective), e0, rtol=1e-10)
    bad = np.array(targets)
    bad[2, 0] = np.nan
    res = fx.solve_ik(model, bad)
    assert res.result == fx.RESULTS.nonfinite_input
    assert np.isnan(float(res.objective)) and np.isnan(float(res.residual))


def test_lm_without_a_conditional_under_jit_and_vmap(toy, rng):
    """Non-finite input skips the iterations inside the loop (no ``lax.cond``): per frame
    under ``vmap`` the bad frame gets ``nonfinite_input``, zero steps and its initial
    pose; the good frames solve as one at a time."""
    m, model = toy
    poses = [random_pose(rng, m.num_joints, 0.3, 0.05) for _ in range(3)]
    targets = np.stack([np.asarray(fx.ik_markers(model, p)) for p in poses])
    targets[1, 4, 2] = np.inf
    init = random_pose(rng, m.num_joints, 0.05, 0.01)
    solver = fx.mesh.LevenbergMarquardt(rtol=1e-8)
    solve = jax.jit(jax.vmap(lambda t: fx.solve_ik(model, t, init, solver=solver)))
    batched = solve(jnp.asarray(targets))
    assert batched.num_steps.shape == (3,) and int(batched.num_steps[1]) == 0
    assert fx.mesh.IK_STATUS[int(batched.status[1])] == "non_finite"
    np.testing.assert_array_equal(batched.pose.angles[1], init.angles)
    for i in (0, 2):
        one = fx.solve_ik(model, targets[i], init, solver=solver)
        assert bool(batched.converged[i]) and bool(one.converged)
        got = fx.Pose(batched.pose.angles[i], batched.pose.translation[i])
        np.testing.assert_allclose(_flat(got), _flat(one.pose), atol=1e-9)


@pytest.mark.slow
def test_lm_from_rest_on_cesium_man_reaches_the_minimum(data_dir):
    """The benchmark's setting (120 markers, a frame of the animation, from rest, rtol
    1e-3): converged, and the posed mesh as close to the true one as the tightly
    converged minimum's (the faster damping schedule loses no accuracy)."""
    path = data_dir / "mesh" / "CesiumMan.glb"
    if not path.exists():
        pytest.skip(f"{path} not found (set FXSPACE_DATA to the data root)")
    m = fx.io.read_gltf(path)
    ms = fx.place_markers(m.vertices, m.faces, 120, seed=0)
    model = fx.ik_model(m, ms)
    anim = m.animation_names[0]
    lo, hi = m.animation_range(anim)
    truth = jnp.asarray(fx.mesh.animation_vertices(m, anim, [lo + 0.37 * (hi - lo)]))[0]
    targets = fx.marker_positions(truth[None], m.faces, ms)[0]
    quick = fx.solve_ik(model, targets, solver=fx.mesh.LevenbergMarquardt(rtol=1e-3))
    tight = fx.solve_ik(model, targets, solver=fx.mesh.LevenbergMarquardt(rtol=1e-12))
    assert bool(quick.converged) and bool(tight.converged)

    def verr(pose):
        return float(jnp.mean(jnp.linalg.norm(fx.pose_vertices(m, pose) - truth, axis=-1)))

    assert verr(quick.pose) <= 1.05 * verr(tight.pose) + 1e-6 * float(model.length_scale)
