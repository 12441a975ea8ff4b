"""Fuzzy c-means: against scikit-fuzzy, known answers, jit/eager, vmap/loop, edge cases."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.cluster._fcm import kmeanspp_extend

skfuzzy = pytest.importorskip("skfuzzy")


def _blobs(rng, n=200, k=4, d=2, spread=3.0):
    centres = rng.normal(scale=spread, size=(k, d))
    lab = rng.integers(0, k, n)
    return centres[lab] + rng.normal(scale=0.4, size=(n, d)), centres


def test_matches_scikit_fuzzy_from_same_memberships(rng):
    X, _ = _blobs(rng, n=250, k=5)
    u0 = rng.uniform(size=(250, 5))
    u0 /= u0.sum(1, keepdims=True)
    res = fx.fuzzy_cmeans(
        jnp.asarray(X), 5, init_memberships=jnp.asarray(u0), tol=1e-12, max_steps=3000
    )
    cntr, u, _, _, jm, _, _ = skfuzzy.cluster.cmeans(
        X.T, 5, 2.0, error=1e-12, maxiter=3000, init=u0.T, seed=0
    )
    assert bool(res.converged)
    np.testing.assert_allclose(np.asarray(res.centers), cntr, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(np.asarray(res.memberships), u.T, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(float(res.objective), jm[-1], rtol=1e-8)


def test_matches_scikit_fuzzy_m_not_two(rng):
    X, _ = _blobs(rng, n=120, k=3)
    u0 = rng.uniform(size=(120, 3))
    u0 /= u0.sum(1, keepdims=True)
    res = fx.fuzzy_cmeans(
        jnp.asarray(X), 3, m=1.7, init_memberships=jnp.asarray(u0), tol=1e-13, max_steps=3000
    )
    cntr, u, *_ = skfuzzy.cluster.cmeans(X.T, 3, 1.7, error=1e-13, maxiter=3000, init=u0.T)
    np.testing.assert_allclose(np.asarray(res.centers), cntr, rtol=1e-7, atol=1e-8)


def test_objective_closed_form_and_rows_sum_to_one(rng, key):
    X, _ = _blobs(rng)
    res = fx.fuzzy_cmeans(jnp.asarray(X), 4, key=key)
    U = np.asarray(res.memberships)
    np.testing.assert_allclose(U.sum(1), 1.0, rtol=1e-12)
    direct = float(fx.fcm_objective(X, res.centers, res.memberships))
    np.testing.assert_allclose(float(res.objective), direct, rtol=1e-10)
    np.testing.assert_allclose(U, np.asarray(fx.fcm_memberships(X, res.centers)), atol=1e-12)


def test_recovers_well_separated_blobs(rng, key):
    X, centres = _blobs(rng, n=400, k=3, spread=20.0)
    res = fx.fuzzy_cmeans(jnp.asarray(X), 3, key=key, n_init=3)
    got = np.asarray(res.centers)
    d = np.linalg.norm(got[:, None] - centres[None], axis=-1)
    assert np.all(d.min(axis=1) < 0.3), d


def test_restarts_pick_lowest_objective(rng):
    X, _ = _blobs(rng, n=150, k=6)
    k = jax.random.PRNGKey(3)
    best = fx.fuzzy_cmeans(jnp.asarray(X), 6, key=k, n_init=4)
    singles = [
        float(fx.fuzzy_cmeans(jnp.asarray(X), 6, key=kk).objective) for kk in jax.random.split(k, 4)
    ]
    np.testing.assert_allclose(float(best.objective), min(singles), rtol=1e-6)


def test_per_entry_tolerance_float32(rng, key):
    X, _ = _blobs(rng, n=300, k=4)
    res = fx.fuzzy_cmeans(jnp.asarray(X, jnp.float32), 4, key=key, tol=1e-5, max_steps=2000)
    assert res.centers.dtype == jnp.float32
    assert bool(res.converged) and int(res.num_steps) < 2000


def test_jit_matches_eager(rng):
    X = jnp.asarray(_blobs(rng, n=60, k=3)[0])
    v0 = X[:3]
    f = lambda x: fx.fuzzy_cmeans(x, 3, init_centers=v0, max_steps=50)
    a = jax.jit(f)(X)
    with jax.disable_jit():
        b = f(X)
    np.testing.assert_allclose(np.asarray(a.centers), np.asarray(b.centers), rtol=1e-9)
    assert int(a.num_steps) == int(b.num_steps)


def test_vmap_matches_loop(rng):
    Xs = jnp.asarray(np.stack([_blobs(rng, n=80, k=3)[0] for _ in range(3)]))
    f = lambda x: fx.fuzzy_cmeans(x, 3, init_centers=x[:3], max_steps=100)
    batched = jax.vmap(f)(Xs)
    for i in range(3):
        one = f(Xs[i])
        np.testing.assert_allclose(
            np.asarray(batched.centers[i]), np.asarray(one.centers), rtol=1e-9, atol=1e-12
        )
        assert int(batched.num_steps[i]) == int(one.num_steps)


def test_coincident_and_duplicate_points_stay_finite(key):
    X = jnp.asarray(np.repeat(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]]), 5, axis=0))
    res = fx.fuzzy_cmeans(X, 6, key=key)  # more centres than distinct points
    assert np.all(np.isfinite(np.asarray(res.centers)))
    assert np.all(np.isfinite(np.asarray(res.memberships)))
    np.testing.assert_allclose(np.asarray(res.memberships).sum(1), 1.0, rtol=1e-9)
    # a sample exactly on a centre belongs to it (up to the distance floor)
    v = jnp.asarray([[0.0, 0.0], [5.0, 5.0]])
    U = np.asarray(fx.fcm_memberships(X[:1], v))
    assert U[0, 0] > 1 - 1e-12


def test_c_equal_n_reaches_zero(rng, key):
    X = jnp.asarray(rng.normal(size=(12, 2)))
    res = fx.fuzzy_cmeans(X, 12, key=key)  # k-means++ seeds every sample
    assert float(res.objective) < 1e-12


def test_kmeanspp_extend_keeps_centres(rng, key):
    X = jnp.asarray(rng.normal(size=(50, 2)))
    v = X[:3]
    ext = kmeanspp_extend(X, v, 4, key)
    assert ext.shape == (7, 2)
    np.testing.assert_array_equal(np.asarray(ext[:3]), np.asarray(v))
    # new centres are samples
    d = np.min(np.linalg.norm(np.asarray(ext[3:])[:, None] - np.asarray(X)[None], axis=-1), 1)
    assert np.all(d == 0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n_clusters=11), "exceeds n_samples"),
        (dict(n_clusters=0), ">= 1"),
        (dict(n_clusters=2, m=1.0), "m .*> 1"),
        (dict(n_clusters=2, criterion="l1"), "criterion"),
        (dict(n_clusters=2, init_centers=np.zeros((3, 2))), "init_centers"),
    ],
)
def test_clear_errors(kwargs, match, key):
    X = jnp.zeros((10, 2))
    with pytest.raises(fx.FxspaceError, match=match):
        fx.fuzzy_cmeans(X, key=key, **kwargs)


def test_needs_key_or_start():
    with pytest.raises(fx.FxspaceError, match="key is required"):
        fx.fuzzy_cmeans(jnp.zeros((10, 2)), 2)
