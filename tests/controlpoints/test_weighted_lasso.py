"""Issue 10: the fused lasso with missing frames (weighted data term, jaxopt proximal
gradient with the exact FLSA prox) against cvxpy, and its argument validation."""

import cvxpy as cp
import numpy as np
import pytest

import fxspace as fx
from fxspace.controlpoints import fused_lasso_solve


def _cvx(y, w, l1, l2):
    b = cp.Variable(len(y))
    yc = np.where(w > 0, y, 0.0)
    obj = 0.5 * cp.sum(cp.multiply(w, (yc - b) ** 2)) + l1 * cp.norm1(b) + l2 * cp.norm1(cp.diff(b))
    cp.Problem(cp.Minimize(obj)).solve(
        solver="CLARABEL", tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12
    )
    return b.value, obj.value


@pytest.mark.parametrize("l1, l2", [(0.0, 1.0), (0.2, 2.0)])
def test_weighted_fused_lasso_matches_cvxpy(rng, l1, l2):
    T = 90
    y = np.repeat(rng.standard_normal(3) * 3, 30)[:, None] + 0.3 * rng.standard_normal((T, 2))
    w = np.ones(T)
    w[20:35] = 0.0  # a 15-frame gap
    w[70] = 0.0
    w[:3] = 0.5  # non-binary weights too
    y[w == 0] = np.nan
    res = fused_lasso_solve(y, l1, l2, weights=w)
    assert bool(res.converged)
    seen = w > 0
    for c in range(2):
        ref, obj = _cvx(y[:, c], w, l1, l2)
        np.testing.assert_allclose(float(res.objective[c]), obj, rtol=1e-8)
        # the minimiser is unique on the observed frames (strictly convex there); inside a
        # gap with λ₁ = 0 any monotone bridge has the same TV, so only the value counts
        np.testing.assert_allclose(np.asarray(res.solution[seen, c]), ref[seen], atol=1e-4)


def test_unit_weights_equal_the_direct_solver(rng):
    y = rng.standard_normal((50, 3))
    a = fused_lasso_solve(y, 0.1, 0.8, weights=np.ones(50))
    b = fused_lasso_solve(y, 0.1, 0.8)
    np.testing.assert_allclose(a.solution, b.solution, atol=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"lam_tv": float("nan")}, "lam_tv must be finite"),
        ({"lam_l1": -1.0}, "lam_l1 must be finite and >= 0"),
        ({"lam_tv": 1j}, "complex"),
        ({"weights": -np.ones(8)}, "weights must be >= 0"),
    ],
)
def test_fused_lasso_arguments(kwargs, match):
    with pytest.raises(fx.FxspaceError, match=match):
        fused_lasso_solve(np.ones((8, 2)), **kwargs)


@pytest.mark.parametrize(
    "Y, match",
    [
        (np.ones(8, np.complex64), "complex"),
        (np.ones(8, np.float16), "float16"),
        (np.ones((0, 2)), "empty"),
        (np.array([1.0, np.nan, 2.0]), "NaN/inf"),
    ],
)
def test_fused_lasso_inputs(Y, match):
    with pytest.raises(fx.FxspaceError, match=match):
        fx.fused_lasso(Y, 0.0, 1.0)


def test_nan_where_weight_positive_is_rejected():
    y = np.array([1.0, np.nan, 2.0, 2.0])
    with pytest.raises(fx.FxspaceError, match="weight is > 0"):
        fused_lasso_solve(y, 0.0, 1.0, weights=np.ones(4))
    res = fused_lasso_solve(y, 0.0, 0.1, weights=np.array([1.0, 0.0, 1.0, 1.0]))
    assert np.isfinite(np.asarray(res.solution)).all()


def test_int_input_converted():
    y = np.array([0, 0, 5, 5, 5])
    np.testing.assert_allclose(fx.fused_lasso(y, 0.0, 1e-3), y, atol=1e-2)
