"""Mesh IK: objective, the three gradients, the Jacobian and the solvers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import finite_difference_jvp
from mesh_toys import _flat, _rel, _unflat, both_views, branching_mesh, random_pose

import fxspace as fx
from fxspace.errors import FxspaceError
from fxspace.io import SkinnedMesh
from fxspace.mesh import ancestor_table


@pytest.fixture(scope="module")
def toy():
    m = branching_mesh(0, uniform_scale=1.7)
    ms = both_views(m, 20, 20)
    return m, fx.ik_model(m, ms)


@pytest.fixture(scope="module")
def cesium(data_dir):
    m = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    ms = fx.place_markers(m.vertices, m.faces, 120, seed=0)
    return m, fx.ik_model(m, ms)


_JIT_GRADS = [
    jax.jit(g) for g in (fx.ik_gradient_naive, fx.ik_gradient_factored, fx.ik_gradient_autodiff)
]


def _grads(model, pose, targets):
    return [g(model, pose, targets) for g in _JIT_GRADS]


def test_objective_is_eq1(toy, rng):
    m, model = toy
    pose = random_pose(rng, m.num_joints)
    targets = jnp.asarray(rng.normal(0, 1, (40, 3)))
    p = fx.marker_positions(
        fx.pose_vertices(m, pose), m.faces, fx.MarkerSet(*both_views(m, 20, 20))
    )
    np.testing.assert_allclose(
        fx.ik_objective(model, pose, targets),
        np.sum((np.asarray(p) - np.asarray(targets)) ** 2),
        rtol=1e-12,
    )


@pytest.mark.parametrize(
    "parents",
    [[-1], [-1, 0], list(range(-1, 11)), [-1, 0, 1, 2, 3, 4, 5, 6, 7, 1, 9, -1, 11, 12]],
    ids=["single", "pair", "chain12", "forest14"],
)
def test_forward_matches_skinned_mesh_at_any_depth(parents, rng):
    """The pointer-jumping forward pass (0, 1, 2 and 3 ternary steps here) against the
    skinned mesh (sequential global transforms), and the gradients against autodiff."""
    m = branching_mesh(1, uniform_scale=1.3, parents=parents)
    ms = both_views(m, 10, 10)
    model = fx.ik_model(m, ms)
    pose = random_pose(rng, m.num_joints)
    np.testing.assert_allclose(
        fx.ik_markers(model, pose),
        fx.marker_positions(fx.pose_vertices(m, pose), m.faces, ms),
        atol=1e-10,
    )
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints))
    naive, fact, auto = _grads(model, pose, targets)
    assert _rel(naive, auto) < 1e-10 and _rel(fact, auto) < 1e-10


def test_three_gradients_agree_and_match_finite_differences(toy, rng):
    m, model = toy
    for _ in range(3):
        pose = random_pose(rng, m.num_joints)
        targets = fx.ik_markers(model, random_pose(rng, m.num_joints))
        naive, fact, auto = _grads(model, pose, targets)
        assert _rel(naive, auto) < 1e-10 and _rel(fact, auto) < 1e-10
        f = lambda x, t=targets: fx.ik_objective(model, _unflat(x, m.num_joints), t)
        x = _flat(pose)
        for _ in range(3):
            v = jnp.asarray(rng.standard_normal(x.shape))
            fd = float(finite_difference_jvp(f, x, v, eps=1e-6))
            np.testing.assert_allclose(float(jnp.vdot(_flat(fact), v)), fd, rtol=1e-6, atol=1e-7)


def test_three_gradients_agree_on_cesium_man(cesium, rng):
    m, model = cesium
    a = m.animation_names[0]
    ms_targets = fx.ik_markers(model, fx.pose_from_local(m, m.sample_animation(a, 0.7)))
    for pose in (fx.rest_pose(m), random_pose(rng, m.num_joints, 0.2, 0.05)):
        naive, fact, auto = _grads(model, pose, ms_targets)
        assert _rel(naive, auto) < 1e-6 and _rel(fact, auto) < 1e-6 and _rel(naive, fact) < 1e-10


def test_gradients_jit_and_vmap(toy, rng):
    m, model = toy
    poses = fx.Pose(
        jnp.asarray(rng.normal(0, 0.3, (3, m.num_joints, 3))),
        jnp.asarray(rng.normal(0, 0.1, (3, 3))),
    )
    targets = fx.ik_markers(model, fx.rest_pose(m))
    for g in (fx.ik_gradient_naive, fx.ik_gradient_factored):
        batched = jax.jit(jax.vmap(g, in_axes=(None, 0, None)))(model, poses, targets)
        jg = jax.jit(g)
        for i in range(3):
            pose = fx.Pose(poses.angles[i], poses.translation[i])
            jitted = jg(model, pose, targets)
            if i == 0:
                assert _rel(jitted, g(model, pose, targets)) < 1e-12  # eager
            assert _rel(fx.Pose(batched.angles[i], batched.translation[i]), jitted) < 1e-12


def test_jacobian_matches_autodiff(toy, rng):
    m, model = toy
    pose = random_pose(rng, m.num_joints)
    p, jac = jax.jit(fx.ik_jacobian)(model, pose)
    ref = jax.jit(jax.jacfwd(fx.ik_markers, argnums=1))(model, pose)
    np.testing.assert_allclose(jac, ref.angles, atol=1e-11)
    np.testing.assert_allclose(p, fx.ik_markers(model, pose), atol=1e-12)


def test_known_pose_recovered(toy, rng):
    m, model = toy
    true = random_pose(rng, m.num_joints, 0.25, 0.1)
    targets = fx.ik_markers(model, true)
    res = fx.solve_ik(model, targets, solver=fx.mesh.solver_from_method(max_steps=100))
    assert bool(res.converged) and float(res.residual) < 1e-6
    # up to the null space: the skinned mesh is recovered, and the angle error lies in the
    # null space of the marker Jacobian
    err = np.abs(np.asarray(fx.pose_vertices(m, res.pose) - fx.pose_vertices(m, true))).max()
    assert err < 1e-4
    _, jac = jax.jit(fx.ik_jacobian)(model, true)
    d = np.asarray(res.pose.angles - true.angles).reshape(-1)
    assert np.linalg.norm(np.asarray(jac).reshape(-1, d.size) @ d) < 1e-4


def test_known_pose_recovered_cesium_man(data_dir, rng):
    m = fx.io.read_gltf(data_dir / "mesh" / "CesiumMan.glb")
    model = fx.ik_model(m, both_views(m, 120, 120))
    true = random_pose(rng, m.num_joints, 0.15, 0.02)
    res = fx.solve_ik(
        model, fx.ik_markers(model, true), solver=fx.mesh.solver_from_method(max_steps=100)
    )
    assert bool(res.converged)
    err = np.abs(np.asarray(fx.pose_vertices(m, res.pose) - fx.pose_vertices(m, true))).max()
    assert err < 1e-3 * np.ptp(m.vertices, axis=0).max()


@pytest.mark.parametrize("method", ["lm", "optx_lm", "adam"])
def test_solvers_reduce_the_objective(toy, rng, method):
    m, model = toy
    true = random_pose(rng, m.num_joints, 0.2, 0.05)
    targets = fx.ik_markers(model, true)
    e0 = float(fx.ik_objective(model, fx.rest_pose(m), targets))
    res = fx.solve_ik(
        model,
        targets,
        solver=fx.mesh.solver_from_method(method, max_steps=200 if method != "adam" else 300),
    )
    assert isinstance(res, fx.IKResult)
    assert 0 < int(res.num_steps) <= 300
    assert float(res.objective) < (1e-10 if method != "adam" else 1e-2) * e0
    np.testing.assert_allclose(res.residual, np.sqrt(res.objective / 40), rtol=1e-12)
    if method != "adam":
        assert bool(res.converged)


def test_adam_with_each_gradient_agrees(toy, rng):
    m, model = toy
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints, 0.2, 0.05))
    out = [
        fx.solve_ik(
            model, targets, solver=fx.mesh.solver_from_method("adam", gradient=g, max_steps=20)
        )
        for g in ("naive", "factored", "autodiff")
    ]
    for r in out[1:]:
        assert _rel(r.pose, out[0].pose) < 1e-8


def test_solve_vmap_vs_loop(toy, rng):
    m, model = toy
    targets = jnp.stack(
        [fx.ik_markers(model, random_pose(rng, m.num_joints, 0.2, 0.05)) for _ in range(3)]
    )
    res = jax.vmap(
        lambda t: fx.solve_ik(model, t, solver=fx.mesh.solver_from_method(max_steps=40))
    )(targets)
    for i in range(3):
        one = fx.solve_ik(model, targets[i], solver=fx.mesh.solver_from_method(max_steps=40))
        assert _rel(fx.Pose(res.pose.angles[i], res.pose.translation[i]), one.pose) < 1e-8
        assert int(res.num_steps[i]) == int(one.num_steps)


@pytest.mark.slow
def test_solve_eager_matches_jit(toy, rng):
    m, model = toy
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints, 0.2, 0.05))[None]
    with jax.disable_jit():
        eager = fx.solve_ik(model, targets[0], solver=fx.mesh.solver_from_method(max_steps=2))
    jitted = fx.solve_ik(model, targets[0], solver=fx.mesh.solver_from_method(max_steps=2))
    assert _rel(eager.pose, jitted.pose) < 1e-8


def test_track_is_warm_started_solve(toy, rng):
    m, model = toy
    base = random_pose(rng, m.num_joints, 0.2, 0.05)
    frames = jnp.stack(
        [
            fx.ik_markers(model, fx.Pose(base.angles * (1 + 0.1 * i), base.translation))
            for i in range(4)
        ]
    )
    tr = fx.track_ik(model, frames, solver=fx.mesh.solver_from_method(max_steps=40))
    assert tr.residual.shape == (4,) and bool(jnp.all(tr.converged))
    pose = fx.rest_pose(m)
    for i in range(4):
        r = fx.solve_ik(model, frames[i], pose, solver=fx.mesh.solver_from_method(max_steps=40))
        pose = r.pose
        assert _rel(fx.Pose(tr.pose.angles[i], tr.pose.translation[i]), pose) < 1e-8
    # warm starts need fewer steps than the first frame from rest
    assert int(tr.num_steps[1:].max()) <= int(tr.num_steps[0])


def test_boundary_errors(toy):
    m, model = toy
    targets = fx.ik_markers(model, fx.rest_pose(m))
    with pytest.raises(FxspaceError, match="targets must have shape"):
        fx.solve_ik(model, targets[:5])
    # not numbers at all: one line naming the argument, not JAX's raw TypeError
    for bad in ("abc", [["x", 1.0, 2.0]] * targets.shape[0]):
        with pytest.raises(FxspaceError, match=r"targets must be a numeric array \(markers, 3\)"):
            fx.solve_ik(model, bad)
    with pytest.raises(FxspaceError, match=r"numeric array \(frames, markers, 3\)"):
        fx.track_ik(model, "abc")
    with pytest.raises(FxspaceError, match="method must be one of"):
        fx.solve_ik(model, targets, solver=fx.mesh.solver_from_method("newton"))
    with pytest.raises(FxspaceError, match="gradient must be one of"):
        fx.solve_ik(model, targets, solver=fx.mesh.solver_from_method("adam", gradient="magic"))
    with pytest.raises(FxspaceError, match="max_steps"):
        fx.solve_ik(model, targets, solver=fx.mesh.solver_from_method(max_steps=0))
    with pytest.raises(FxspaceError, match="init must be a Pose"):
        fx.solve_ik(model, targets, fx.rest_pose(3))
    with pytest.raises(FxspaceError, match="frames, markers, 3"):
        fx.track_ik(model, targets)
    bad = branching_mesh(0)
    bad = SkinnedMesh(
        **{f: getattr(bad, f) for f in bad.__dataclass_fields__ if f != "rest_scales"},
        rest_scales=np.array([[1.0, 2.0, 1.0]] * 6),
    )
    with pytest.raises(FxspaceError, match="non-uniform"):
        fx.ik_model(bad, fx.place_markers(bad.vertices, bad.faces, 3))
    assert ancestor_table(m.parents).shape[0] == m.num_joints


def test_normal_equations_match_the_dense_jacobian(toy, rng):
    m, model = toy
    pose = random_pose(rng, m.num_joints)
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints))
    r, g, h = jax.jit(fx.ik_normal_equations)(model, pose, targets)
    _, jac = jax.jit(fx.ik_jacobian)(model, pose)
    nk, nj = targets.shape[0], m.num_joints
    jm = np.concatenate([np.asarray(jac).reshape(3 * nk, 3 * nj), np.tile(np.eye(3), (nk, 1))], 1)
    rr = np.asarray(r).reshape(-1)
    np.testing.assert_allclose(g, jm.T @ rr, atol=1e-10 * np.abs(jm.T @ rr).max())
    np.testing.assert_allclose(h, jm.T @ jm, atol=1e-10 * np.abs(jm.T @ jm).max())
    # and Jᵀδ is half the objective's gradient
    np.testing.assert_allclose(
        2 * g, _flat(fx.ik_gradient_factored(model, pose, targets)), rtol=1e-9, atol=1e-9
    )
