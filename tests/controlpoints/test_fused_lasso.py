"""Fused lasso (FLSA): vs prox_tv / cvxpy, exact step recovery, jit/vmap/grad."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import check_grad, finite_difference_jvp

import fxspace as fx
from fxspace.controlpoints._fused_lasso import _group_mean


def _reference(y, l1, l2):
    """Independent reference: prox_tv's tv1_1d + soft-threshold, else cvxpy."""
    try:
        import prox_tv as ptv

        x = ptv.tv1_1d(np.asarray(y, float), float(l2))
        return np.sign(x) * np.maximum(np.abs(x) - l1, 0.0)
    except ImportError:
        cp = pytest.importorskip("cvxpy")
        b = cp.Variable(len(y))
        obj = 0.5 * cp.sum_squares(y - b) + l1 * cp.norm1(b) + l2 * cp.norm1(cp.diff(b))
        cp.Problem(cp.Minimize(obj)).solve(solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12)
        return np.asarray(b.value)


def _cvxpy(y, l1, l2):
    cp = pytest.importorskip("cvxpy")
    b = cp.Variable(len(y))
    obj = 0.5 * cp.sum_squares(y - b) + l1 * cp.norm1(b) + l2 * cp.norm1(cp.diff(b))
    cp.Problem(cp.Minimize(obj)).solve(solver=cp.CLARABEL)
    return np.asarray(b.value)


@pytest.mark.parametrize("T", [2, 3, 7, 40, 150])
def test_matches_reference_on_random_signals(rng, T):
    for _ in range(6):
        y = rng.standard_normal(T) * rng.uniform(0.2, 4.0)
        l1, l2 = rng.uniform(0, 0.5), rng.uniform(0.01, 3.0)
        ours = np.asarray(fx.fused_lasso(y[:, None], l1, l2))[:, 0]
        ref = _reference(y, l1, l2)
        o = float(fx.flsa_objective(y, ours, l1, l2))
        r = float(fx.flsa_objective(y, ref, l1, l2))
        assert o <= r + 1e-9 * (1 + abs(r))
        np.testing.assert_allclose(ours, ref, atol=1e-7)


def test_matches_cvxpy_multichannel(rng):
    Y = rng.standard_normal((30, 4))
    lams = np.array([0.1, 0.5, 1.0, 2.0])
    ours = np.asarray(fx.fused_lasso(Y, 0.2, lams))
    for c in range(4):
        ref = _cvxpy(Y[:, c], 0.2, lams[c])
        o = float(fx.flsa_objective(Y[:, c], ours[:, c], 0.2, lams[c]))
        r = float(fx.flsa_objective(Y[:, c], ref, 0.2, lams[c]))
        assert o <= r + 1e-7 * (1 + abs(r))  # ours is exact; the interior point is approximate
        np.testing.assert_allclose(ours[:, c], ref, atol=1e-4)


def test_exact_piecewise_constant_recovery():
    """Noiseless steps: TV shrinks each plateau by a known amount, λ→0 recovers exactly."""
    steps = np.repeat([0.0, 4.0, -2.0, 1.0], 10)
    np.testing.assert_allclose(np.asarray(fx.fused_lasso(steps, 0.0, 1e-12)), steps, atol=1e-10)
    # known closed form: interior plateau of length n moves by λ(±1 ±1)/n
    lam = 0.5
    out = np.asarray(fx.fused_lasso(steps, 0.0, lam))
    expected = np.repeat(
        [0.0 + lam / 10, 4.0 - 2 * lam / 10, -2.0 + 2 * lam / 10, 1.0 - lam / 10], 10
    )
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert len(np.unique(np.round(out, 9))) == 4  # exactly 4 plateaus, 3 change points


def test_large_lambda_gives_mean_and_l1_soft_threshold(rng):
    y = rng.standard_normal(25)
    np.testing.assert_allclose(
        np.asarray(fx.fused_lasso(y, 0.0, 1e3)), np.full(25, y.mean()), atol=1e-12
    )
    l1 = 0.3
    np.testing.assert_allclose(
        np.asarray(fx.fused_lasso(y, l1, 0.0)),
        np.sign(y) * np.maximum(np.abs(y) - l1, 0),
        atol=1e-12,
    )


def test_dual_jaxopt_solver_agrees(rng):
    Y = rng.standard_normal((40, 3))
    direct = fx.fused_lasso_solve(Y, 0.1, 0.7)
    dual = fx.fused_lasso_solve(Y, 0.1, 0.7, method="dual")
    assert bool(direct.converged)
    gap = np.asarray(dual.objective - direct.objective) / np.asarray(direct.objective)
    assert np.all(gap >= -1e-12) and np.all(gap < 1e-6)
    np.testing.assert_allclose(np.asarray(dual.solution), np.asarray(direct.solution), atol=1e-3)


def test_shapes_jit_vmap(rng):
    Y = rng.standard_normal((20, 3, 2))
    out = fx.fused_lasso(Y, 0.1, 0.5)
    assert out.shape == Y.shape
    jitted = jax.jit(lambda y: fx.fused_lasso(y, 0.1, 0.5))(Y)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(out), atol=1e-12)
    lams = jnp.array([0.1, 0.5, 1.0])
    vm = jax.vmap(lambda lam: fx.fused_lasso(Y[:, 0, 0], 0.0, lam))(lams)
    loop = np.stack([np.asarray(fx.fused_lasso(Y[:, 0, 0], 0.0, float(lam))) for lam in lams])
    np.testing.assert_allclose(np.asarray(vm), loop, atol=1e-12)


def test_gradients_vs_finite_differences(rng):
    y = jnp.asarray(rng.standard_normal(30))
    w = jnp.asarray(rng.standard_normal(30))
    f = lambda y: jnp.sum(w * fx.fused_lasso(y, 0.1, 0.4) ** 2)
    check_grad(f, y, rng, eps=1e-7, rtol=1e-5)
    g = lambda lam: jnp.sum(w * fx.fused_lasso(y, 0.1, lam))
    an = float(jax.grad(g)(0.4))
    fd = float(finite_difference_jvp(g, 0.4, 1.0, eps=1e-7))
    assert np.isclose(an, fd, rtol=1e-5, atol=1e-8)
    h = lambda l1: jnp.sum(w * fx.fused_lasso(y, l1, 0.4))
    assert np.isclose(
        float(jax.grad(h)(0.1)),
        float(finite_difference_jvp(h, 0.1, 1.0, eps=1e-7)),
        rtol=1e-5,
        atol=1e-8,
    )


def test_group_mean():
    g = jnp.arange(6.0)[:, None]
    starts = jnp.array([True, False, True, False, False, True])[:, None]
    np.testing.assert_allclose(np.asarray(_group_mean(g, starts))[:, 0], [0.5, 0.5, 3, 3, 3, 5])


def test_boundary_errors():
    with pytest.raises(fx.FxspaceError, match="NaN"):
        fx.fused_lasso(np.array([0.0, np.nan, 1.0]), 0.0, 1.0)
    with pytest.raises(fx.FxspaceError, match=">= 0"):
        fx.fused_lasso(np.zeros(5), 0.0, -1.0)
    with pytest.raises(fx.FxspaceError, match="broadcast"):
        fx.fused_lasso(np.zeros((5, 3)), 0.0, np.ones(4))
    with pytest.raises(fx.FxspaceError, match="method"):
        fx.fused_lasso(np.zeros(5), 0.0, 1.0, method="admm")


def test_default_path_is_one_jaxopt_prox_gradient_step_and_reports_results(rng):
    """The default solve goes through jaxopt's ProximalGradient whose prox is the exact
    FLSA prox: same answer as calling the prox directly; the result vocabulary is set,
    NaN input is never 'successful' and raises with throw=True."""
    from fxspace.controlpoints._fused_lasso import _condat_chunked, _soft

    Y = rng.standard_normal((40, 5))
    res = fx.fused_lasso_solve(Y, 0.1, 0.7)
    x, _, _, _ = _condat_chunked(jnp.asarray(Y.T), jnp.full(5, 0.7), 4 * 40 * 40 + 64)
    np.testing.assert_allclose(np.asarray(res.solution), np.asarray(_soft(x.T, 0.1)), atol=1e-12)
    assert res.result == fx.RESULTS.successful and bool(res.converged)
    assert int(res.stats["max_steps"]) == 4 * 40 * 40 + 64 and int(res.num_steps) > 0
    bad = Y.copy()
    bad[3, 1] = np.nan
    out = jax.jit(lambda y: fx.fused_lasso_solve(y, 0.0, 1.0).result)(jnp.asarray(bad))
    assert out != fx.RESULTS.successful
    with pytest.raises(fx.FxspaceError, match="fused_lasso: the iteration limit"):
        fx.fused_lasso_solve(Y, 0.0, 1.0, weights=np.ones(40), max_steps=1, throw=True)
