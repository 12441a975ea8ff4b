"""Mesh IK, issue 18/23: results vocabulary, solver objects, data as pytrees, and the
constraints as residuals in every solver (marker weights, surface normals, plane
contact, joint limits, prior)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mesh_toys import _flat, _unflat, both_views, branching_mesh, random_pose

import fxspace as fx
from fxspace.errors import FxspaceError


@pytest.fixture(scope="module")
def toy():
    m = branching_mesh(0, uniform_scale=1.7)
    ms = both_views(m, 20, 20)
    return m, ms, fx.ik_model(m, ms)


def _all_constraints(m, ms, model, rng):
    nk = model.marker_joints.shape[0]
    return fx.mesh.ik_constraints(
        model,
        marker_weights=rng.uniform(0.5, 2.0, nk),
        normal=fx.mesh.normal_constraint(m, ms, weight=0.7, indices=[0, 3, 5]),
        contact=fx.mesh.plane_contact(model, [1, 4], normal=(0.2, 1.0, 0.1), offset=0.3),
        limits=fx.mesh.joint_limits(model, 0.1, weight=2.0),
        prior=fx.mesh.joint_prior(model, 0.3, to="previous"),
    )


def test_constraint_blocks_match_autodiff(toy, rng):
    """LM's ``(F, Jᵀr, JᵀJ)`` and the factored / naive gradients of every block against
    ``jax.jacfwd`` / ``jax.grad`` of the stacked residual vector."""
    m, ms, model = toy
    cons = _all_constraints(m, ms, model, rng)
    pose, init = random_pose(rng, m.num_joints), random_pose(rng, m.num_joints)
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints))
    tn = fx.mesh.marker_normals(cons.normal.corners, random_pose(rng, m.num_joints))
    nj = m.num_joints

    def resid(x):
        return fx.mesh.constraint_residuals(model, cons, _unflat(x, nj), targets, init, tn)

    x = _flat(pose)
    r, jac = jax.jit(resid)(x), jax.jit(jax.jacfwd(resid))(x)
    obj, g, h = jax.jit(fx.mesh.constrained_normal_equations)(model, cons, pose, targets, init, tn)
    np.testing.assert_allclose(float(obj), float(r @ r), rtol=1e-10)
    np.testing.assert_allclose(g, jac.T @ r, rtol=1e-8, atol=1e-9 * float(jnp.abs(g).max()))
    hh = jac.T @ jac
    np.testing.assert_allclose(h, hh, rtol=1e-8, atol=1e-9 * float(jnp.abs(hh).max()))
    for form in ("factored", "naive", "autodiff"):
        vg = jax.jit(fx.mesh.constrained_value_and_gradient, static_argnums=0)
        v, gr = vg(form, model, cons, pose, targets, init, tn)
        np.testing.assert_allclose(float(v), float(r @ r), rtol=1e-10)
        np.testing.assert_allclose(_flat(gr), 2 * jac.T @ r, rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("solver", [fx.mesh.LevenbergMarquardt(), fx.mesh.BFGS(max_steps=400)])
def test_floor_contact_keeps_a_marker_on_the_plane(toy, rng, solver):
    """A contact at y = floor (the marker's target is free) holds the marker on the plane
    to far better than 1 mm in mesh units of a ~1 m toy, while the others are fitted."""
    m, _, model = toy
    true = random_pose(rng, m.num_joints, 0.3, 0.05)
    targets = np.array(fx.ik_markers(model, true))
    foot = 2
    floor = float(targets[foot, 1]) - 0.2  # the marker must move 0.2 down to touch it
    w = np.ones(targets.shape[0])
    w[foot] = 0.0
    cons = fx.mesh.ik_constraints(
        model,
        marker_weights=w,
        contact=fx.mesh.plane_contact(model, [foot], normal=(0, 1, 0), offset=floor, weight=1e4),
    )
    free = fx.solve_ik(model, targets, solver=solver)
    res = fx.solve_ik(model, targets, solver=solver, constraints=cons)
    y = float(fx.ik_markers(model, res.pose)[foot, 1])
    assert abs(y - floor) < 1e-3 * float(model.length_scale) / 2
    assert abs(float(fx.ik_markers(model, free.pose)[foot, 1]) - floor) > 0.15
    others = np.delete(np.arange(targets.shape[0]), foot)
    err = np.linalg.norm(
        np.asarray(fx.ik_markers(model, res.pose))[others] - targets[others], axis=1
    )
    assert float(np.sqrt(np.mean(err**2))) < 0.1 * float(model.length_scale)


def test_normal_constraint_moves_the_lm_solution(toy, rng):
    """Under LM (before: BFGS/Adam only) the normal constraint changes the pose, and with
    the true pose's normals and few markers it brings the pose closer to the truth."""
    m, ms, model = toy
    true = random_pose(rng, m.num_joints, 0.3, 0.05)
    nc = fx.mesh.normal_constraint(m, ms, weight=1.0)
    tn = fx.mesh.marker_normals(nc.corners, true)
    targets = fx.ik_markers(model, true)
    cons = fx.mesh.ik_constraints(model, normal=nc)
    a = fx.solve_ik(model, targets, solver=fx.mesh.solver_from_method(max_steps=100))
    b = fx.solve_ik(
        model,
        targets,
        constraints=cons,
        target_normals=tn,
        solver=fx.mesh.solver_from_method(max_steps=100),
    )
    assert b.result == fx.RESULTS.successful
    np.testing.assert_allclose(fx.mesh.marker_normals(nc.corners, b.pose), tn, atol=1e-5)
    # the wrong normals pull the pose away from the marker fit
    c = fx.solve_ik(
        model,
        targets,
        constraints=cons,
        target_normals=-tn,
        solver=fx.mesh.solver_from_method(max_steps=100),
    )
    assert float(jnp.abs(c.pose.angles - a.pose.angles).max()) > 1e-2


def test_nan_targets_give_a_result_code_and_throw(toy):
    m, _, model = toy
    targets = np.array(fx.ik_markers(model, fx.rest_pose(m)))
    targets[0, 0] = np.nan
    res = fx.solve_ik(model, targets)
    assert res.result != fx.RESULTS.successful
    assert res.result == fx.RESULTS.nonfinite_input
    assert not bool(res.converged) and int(res.status) == 2
    assert int(res.stats["max_steps"]) == 50
    with pytest.raises(FxspaceError, match="solve_ik: the input holds NaN"):
        fx.solve_ik(model, targets, throw=True)
    frames = np.stack([np.asarray(fx.ik_markers(model, fx.rest_pose(m)))] * 3)
    frames[2, 1, 1] = np.inf
    with pytest.raises(FxspaceError, match=r"track_ik: .*element 2 of 3"):
        fx.track_ik(model, frames, throw=True)
    ok = fx.solve_ik(model, frames[0], throw=True)
    assert ok.result == fx.RESULTS.successful
    one = fx.solve_ik(model, frames[0] + 1.0, solver=fx.mesh.LevenbergMarquardt(max_steps=1))
    assert one.result == fx.RESULTS.max_steps_reached and int(one.status) == 1


def test_solver_objects_and_the_string_alias(toy, rng):
    m, _, model = toy
    lm = fx.mesh.LevenbergMarquardt(rtol=1e-3, atol=1e-8, max_steps=20)
    assert hash(lm) == hash(fx.mesh.LevenbergMarquardt(rtol=1e-3, atol=1e-8, max_steps=20))
    with pytest.raises(dataclasses.FrozenInstanceError):
        lm.rtol = 1.0  # type: ignore[misc]
    assert fx.mesh.solver_from_method("bfgs", gradient="naive", rtol=1e-3) == fx.mesh.BFGS(
        rtol=1e-3, gradient="naive"
    )
    targets = fx.ik_markers(model, random_pose(rng, m.num_joints, 0.3, 0.05))
    a = fx.solve_ik(
        model, targets, solver=fx.mesh.solver_from_method("lm", rtol=1e-3, atol=1e-8, max_steps=20)
    )
    b = fx.solve_ik(model, targets, solver=lm)
    np.testing.assert_array_equal(a.pose.angles, b.pose.angles)
    jitted = jax.jit(lambda t: fx.solve_ik(model, t, solver=lm).pose.angles)
    np.testing.assert_allclose(jitted(targets), b.pose.angles, atol=1e-12)
    # the old keyword front is gone: a method name goes through solver_from_method
    for old in ("method", "gradient", "max_steps", "rtol", "atol", "learning_rate"):
        with pytest.raises(TypeError, match=old):
            fx.solve_ik(model, targets, **{old: "bfgs" if old == "method" else 10})
        with pytest.raises(TypeError, match=old):
            fx.track_ik(model, targets[None], **{old: "bfgs" if old == "method" else 10})
    with pytest.raises(TypeError, match="regularization"):
        fx.solve_ik(model, targets, regularization=None)
    reg = fx.mesh.ik_regularization(model, prior=1e-3)
    with pytest.raises(FxspaceError, match="constraints_from_regularization"):
        fx.solve_ik(model, targets, constraints=reg)
    with pytest.raises(FxspaceError, match="solver_from_method"):
        fx.solve_ik(model, targets, solver="bfgs")
    with pytest.raises(FxspaceError, match="max_steps must be >= 1"):
        fx.mesh.BFGS(max_steps=0)
    with pytest.raises(FxspaceError, match="max_steps must be an integer"):
        fx.mesh.LevenbergMarquardt(max_steps=2.5)
    with pytest.raises(FxspaceError, match="rtol must be a finite number"):
        fx.mesh.LevenbergMarquardt(rtol=float("nan"))
    with pytest.raises(FxspaceError, match="gradient must be one of"):
        fx.mesh.Adam(gradient="magic")
    with pytest.raises(FxspaceError, match="solver must be"):
        fx.solve_ik(model, targets, solver="lm")


def test_mesh_and_constraints_are_pytrees(toy, rng):
    m, ms, model = toy
    leaves, tree = jax.tree_util.tree_flatten(m)
    assert len(leaves) == 9 and all(isinstance(x, np.ndarray) for x in leaves)
    back = jax.tree_util.tree_unflatten(tree, leaves)
    assert back.joint_names == m.joint_names and np.array_equal(back.parents, m.parents)
    pose = random_pose(rng, m.num_joints)
    tables = fx.mesh.skin_tables(m)
    v = jax.jit(fx.mesh.pose_vertices)(m, pose, tables)
    np.testing.assert_allclose(v, fx.pose_vertices(m, pose), atol=1e-12)
    cons = _all_constraints(m, ms, model, rng)
    assert len(jax.tree_util.tree_leaves(cons)) > 10
    assert fx.mesh.ik_constraints(model).normal is None


def test_constraint_builders_refuse_bad_input(toy):
    m, ms, model = toy
    with pytest.raises(FxspaceError, match="marker indices must be distinct"):
        fx.mesh.plane_contact(model, [0, 0])
    with pytest.raises(FxspaceError, match="normal must be a finite non-zero"):
        fx.mesh.plane_contact(model, [0], normal=(0, 0, 0))
    with pytest.raises(FxspaceError, match="weight must be > 0"):
        fx.mesh.joint_limits(model, 0.5, weight=-1.0)
    with pytest.raises(FxspaceError, match="marker_weights must be"):
        fx.mesh.ik_constraints(model, marker_weights=[1.0])
    targets = fx.ik_markers(model, fx.rest_pose(m))
    cons = fx.mesh.ik_constraints(model, normal=fx.mesh.normal_constraint(m, ms, indices=[1]))
    with pytest.raises(FxspaceError, match="needs target_normals"):
        fx.solve_ik(model, targets, constraints=cons)
    with pytest.raises(FxspaceError, match="without a normal constraint"):
        fx.solve_ik(model, targets, target_normals=np.zeros((1, 3)))


@pytest.mark.slow
def test_cesium_man_floor_and_normals(data_dir, rng):
    """On the shipped human: a foot marker on the floor plane under LM and BFGS while 40
    other markers are fitted, and the normal constraint moves the LM solution."""
    path = data_dir / "mesh" / "CesiumMan.glb"
    if not path.exists():
        pytest.skip(f"{path} not found (set FXSPACE_DATA to the data root)")
    mesh = fx.io.read_gltf(path)
    anim = mesh.animation_names[0]
    t = 0.3 * sum(mesh.animation_range(anim))
    posed = fx.mesh.animation_vertices(mesh, anim, [t])[0]  # world coordinates
    up = int(np.argmax(np.ptp(posed, axis=0)))  # the body's long axis
    faces = np.asarray(mesh.faces)
    low = int(np.argmin(posed[faces].mean(axis=1)[:, up]))  # the lowest triangle: a foot
    v = np.asarray(mesh.vertices)
    nrm = np.asarray(fx.triangle_normals(v, faces))[low]
    foot_ms = fx.place_markers(
        v, faces, 1, view_dir=-nrm, triangles=[low], barycentric=[[1 / 3, 1 / 3, 1 / 3]]
    )
    ms = fx.place_markers(v, faces, 40, seed=1)
    ms = fx.MarkerSet(
        jnp.concatenate([ms.triangles, foot_ms.triangles]),
        jnp.concatenate([ms.barycentric, foot_ms.barycentric]),
    )
    model = fx.ik_model(mesh, ms)
    targets = fx.marker_positions(jnp.asarray(posed), faces, ms)
    foot = targets.shape[0] - 1
    n = np.zeros(3)
    n[up] = 1.0
    floor = float(posed[:, up].min()) - 0.02  # 2 cm below the foot: the contact must act
    w = np.ones(targets.shape[0])
    w[foot] = 0.0
    cons = fx.mesh.ik_constraints(
        model,
        marker_weights=w,
        contact=fx.mesh.plane_contact(model, [foot], normal=n, offset=floor, weight=1e4),
    )
    mm = 1e-3 / 1.0  # CesiumMan is about 1.5 m tall, in metres
    for solver in (fx.mesh.LevenbergMarquardt(max_steps=100), fx.mesh.BFGS(max_steps=400)):
        res = fx.solve_ik(model, targets, solver=solver, constraints=cons)
        p = np.asarray(fx.ik_markers(model, res.pose))
        assert abs(p[foot, up] - floor) <= mm, type(solver).__name__
        assert float(res.residual) < 0.05 * float(model.length_scale)
    nc = fx.mesh.normal_constraint(mesh, ms, weight=1.0, indices=np.arange(10))
    tn = -fx.mesh.marker_normals(nc.corners, fx.rest_pose(mesh))
    a = fx.solve_ik(model, targets)
    b = fx.solve_ik(
        model, targets, constraints=fx.mesh.ik_constraints(model, normal=nc), target_normals=tn
    )
    assert float(jnp.abs(a.pose.angles - b.pose.angles).max()) > 1e-2
