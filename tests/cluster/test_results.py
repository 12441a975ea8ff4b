"""Issue 18: every clustering result carries `.result`, `.num_steps`, `.stats`; `throw=`."""

import equinox as eqx
import jax
import numpy as np
import pytest

import fxspace as fx


@pytest.fixture
def points(rng):
    return np.concatenate([rng.standard_normal((40, 2)), rng.standard_normal((40, 2)) + 6])


def _fcm(x, **kw):
    return fx.fuzzy_cmeans(x, 2, key=jax.random.PRNGKey(0), **kw)


def _kkm(x, **kw):
    return fx.kernel_kmeans(x, 2, 0.5, key=jax.random.PRNGKey(0), n_init=2, **kw)


def _sparse(x, **kw):
    return fx.cluster.fuzzy_cmeans(x, 2, nearest=2, key=jax.random.PRNGKey(0), **kw)


# the truncated-membership FCM (fuzzy_cmeans with nearest) reports under the same name
ROUTINES = [("fuzzy_cmeans", _fcm), ("kernel_kmeans", _kkm), ("fuzzy_cmeans", _sparse)]


@pytest.mark.parametrize("name, run", ROUTINES)
def test_successful_result_vocabulary(points, name, run):
    res = run(points)
    assert res.result == fx.RESULTS.successful
    assert bool(res.converged) and fx.RESULTS[res.result] == ""
    assert int(res.num_steps) >= 1
    assert isinstance(res.stats, dict) and "max_steps" in res.stats
    assert all(np.ndim(v) == 0 for v in res.stats.values())
    assert run(points, throw=True).result == fx.RESULTS.successful


@pytest.mark.parametrize("name, run", ROUTINES)
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_input_result_and_throw(points, name, run, bad):
    X = points.copy()
    X[5, 1] = bad
    res = run(X)
    assert res.result == fx.RESULTS.nonfinite_input
    assert res.result != fx.RESULTS.successful and not bool(res.converged)
    with pytest.raises(fx.FxspaceError, match=r"holds NaN/inf.*\(5, 1\)"):
        run(X, throw=True)


@pytest.mark.parametrize("name, run", ROUTINES)
def test_throw_under_jit_goes_through_error_if(points, name, run):
    f = jax.jit(lambda x: run(x, throw=True))
    assert f(points).result == fx.RESULTS.successful
    X = points.copy()
    X[0] = np.nan
    with pytest.raises(Exception, match=f"{name}: the input holds NaN or inf"):
        jax.block_until_ready(f(X))


def test_throw_under_filter_jit(points):
    X = points.copy()
    X[0] = np.nan
    g = eqx.filter_jit(lambda x: _fcm(x, throw=True))
    with pytest.raises(Exception, match="fuzzy_cmeans: the input holds NaN or inf"):
        jax.block_until_ready(g(X))


def test_max_steps_reached_is_reported_and_raised(points):
    res = fx.fuzzy_cmeans(points, 3, key=jax.random.PRNGKey(1), max_steps=1, check_every=1)
    assert res.result == fx.RESULTS.max_steps_reached and not bool(res.converged)
    assert int(res.stats["max_steps"]) == 1 and int(res.num_steps) == 1
    with pytest.raises(fx.FxspaceError, match="fuzzy_cmeans: the iteration limit"):
        fx.fuzzy_cmeans(
            points, 3, key=jax.random.PRNGKey(1), max_steps=1, check_every=1, throw=True
        )
    km = fx.kernel_kmeans(points, 3, 0.5, key=jax.random.PRNGKey(1), n_init=2, max_steps=0)
    assert km.result == fx.RESULTS.max_steps_reached
    with pytest.raises(fx.FxspaceError, match="kernel_kmeans: the iteration limit"):
        fx.kernel_kmeans(points, 3, 0.5, n_init=2, max_steps=0, throw=True)


def test_results_vmap_over_inputs(points):
    X = np.stack([points, points.copy()])
    X[1, 0, 0] = np.nan
    res = jax.vmap(lambda x: fx.fuzzy_cmeans(x, 2, key=jax.random.PRNGKey(0)))(X)
    ok = np.asarray(res.result == fx.RESULTS.successful)
    assert ok.tolist() == [True, False]
    assert np.asarray(res.result == fx.RESULTS.nonfinite_input).tolist() == [False, True]
