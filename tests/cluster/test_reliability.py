"""Issue 10, case 5: clustering never reports convergence on garbage."""

import jax
import numpy as np
import pytest

import fxspace as fx


@pytest.fixture
def points(rng):
    return np.concatenate([rng.standard_normal((60, 2)), rng.standard_normal((60, 2)) + 6])


def test_kernel_kmeans_nan_point_is_named(points):
    X = points.copy()
    X[7, 1] = np.nan
    with pytest.raises(fx.FxspaceError, match=r"X holds NaN/inf.*\(7, 1\)"):
        fx.kernel_kmeans(X, 2, 0.5, throw=True)
    res = fx.kernel_kmeans(X, 2, 0.5, n_init=2)  # throw=False: reported, not raised
    assert res.result == fx.RESULTS.nonfinite_input
    assert res.result != fx.RESULTS.successful and not bool(res.converged)
    assert int(res.num_steps) == 0 and (np.asarray(res.labels) == -1).all()


@pytest.mark.parametrize("gamma", [0.0, -1.0, float("nan"), float("inf")])
def test_kernel_kmeans_bad_gamma(points, gamma):
    with pytest.raises(fx.FxspaceError, match="gamma"):
        fx.kernel_kmeans(points, 2, gamma)


def test_kernel_kmeans_under_jit_reports_not_converged(points):
    X = points.copy()
    X[3] = np.nan
    res = jax.jit(lambda x: fx.kernel_kmeans_gram(fx.gaussian_kernel(x, 0.5), 2, n_init=2))(X)
    assert not bool(res.converged)
    ok = fx.kernel_kmeans(points, 2, 0.5, n_init=2)
    assert bool(ok.converged)
    # the two blobs are found (scikit-learn's KMeans gives the same partition)
    from sklearn.cluster import KMeans

    ref = KMeans(2, n_init=4, random_state=0).fit_predict(points)
    lab = np.asarray(ok.labels)
    assert (lab == ref).all() or (lab == 1 - ref).all()


def test_fuzzy_cmeans_nan_point(points):
    X = points.copy()
    X[0, 0] = np.nan
    with pytest.raises(fx.FxspaceError, match=r"x holds NaN/inf.*\(0, 0\)"):
        fx.fuzzy_cmeans(X, 2, key=jax.random.PRNGKey(0), throw=True)
    res = fx.fuzzy_cmeans(X, 2, key=jax.random.PRNGKey(0))
    assert res.result == fx.RESULTS.nonfinite_input and not bool(res.converged)
    assert not np.isfinite(np.asarray(res.centers)).all()  # no plausible finite answer
    res = jax.jit(lambda x: fx.fuzzy_cmeans(x, 2, key=jax.random.PRNGKey(0)))(X)
    assert not bool(res.converged) and res.result == fx.RESULTS.nonfinite_input
    ok = fx.fuzzy_cmeans(points, 2, key=jax.random.PRNGKey(0))
    assert bool(ok.converged)


@pytest.mark.parametrize(
    "x, match",
    [
        (np.zeros((10, 2), np.complex64), "complex"),
        (np.zeros((10, 2), np.float16), "float16"),
        (np.zeros((0, 2)), "empty"),
    ],
)
def test_cluster_dtype_policy(x, match):
    with pytest.raises(fx.FxspaceError, match=match):
        fx.fuzzy_cmeans(x, 1, key=jax.random.PRNGKey(0))
    with pytest.raises(fx.FxspaceError, match=match):
        fx.kernel_kmeans(x, 1, 1.0)


def test_cluster_int_points_converted(points):
    X = np.rint(points * 10).astype(np.int32)
    res = fx.fuzzy_cmeans(X, 2, key=jax.random.PRNGKey(0))
    assert np.asarray(res.centers).dtype.kind == "f" and bool(res.converged)
