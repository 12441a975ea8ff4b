"""Kernel k-means: vs a numpy reference from the same initialisation, known clusters, jit/vmap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx


def _numpy_kernel_kmeans(K, labels, n_clusters, max_iter=100):
    """Plain Lloyd iteration of kernel k-means (Dhillon et al. 2004), numpy, no tricks."""
    labels = labels.copy()
    n = K.shape[0]
    for _ in range(max_iter):
        d = np.full((n, n_clusters), np.inf)
        for c in range(n_clusters):
            m = labels == c
            if m.any():
                d[:, c] = (
                    np.diag(K) - 2 * K[:, m].sum(1) / m.sum() + K[np.ix_(m, m)].sum() / m.sum() ** 2
                )
        new = d.argmin(1)
        if np.array_equal(new, labels):
            break
        labels = new
    obj = sum(d[i, labels[i]] for i in range(n))
    return labels, obj


def _blobs(rng, k=4, n=30, spread=0.3):
    centres = rng.standard_normal((k, 2)) * 4
    X = np.concatenate([c + spread * rng.standard_normal((n, 2)) for c in centres])
    return X, np.repeat(np.arange(k), n)


def test_matches_numpy_reference_same_init(rng):
    X, _ = _blobs(rng, k=5, spread=1.5)
    gamma = 0.2
    K = np.asarray(fx.gaussian_kernel(X, gamma))
    for _ in range(3):
        init = rng.integers(0, 5, len(X))
        ref_labels, ref_obj = _numpy_kernel_kmeans(K, init, 5)
        res = fx.kernel_kmeans(X, 5, gamma, init=init[None], max_steps=100)
        np.testing.assert_array_equal(np.asarray(res.labels), ref_labels)
        assert np.isclose(float(res.objective), ref_obj, rtol=1e-10)
        assert bool(res.converged)


def test_recovers_separated_clusters(rng, key):
    X, truth = _blobs(rng)
    res = fx.kernel_kmeans(X, 4, 0.5, key=key, n_init=5)
    # same partition up to relabelling
    pairs = {(int(a), int(b)) for a, b in zip(np.asarray(res.labels), truth, strict=True)}
    assert len(pairs) == 4
    assert sorted(np.asarray(res.sizes).tolist()) == [30, 30, 30, 30]
    assert res.restart_objectives.shape == (5,)
    assert float(res.objective) == pytest.approx(float(jnp.min(res.restart_objectives)))
    # medoid: a member of its own cluster, nearest to the centre in feature space
    K = np.asarray(fx.gaussian_kernel(X, 0.5))
    lab = np.asarray(res.labels)
    for c, m in enumerate(np.asarray(res.medoids)):
        assert lab[m] == c
        mem = lab == c
        d = np.diag(K)[mem] - 2 * K[np.ix_(mem, mem)].mean(1)
        assert np.argmin(d) == np.nonzero(mem)[0].tolist().index(m)


def test_best_restart_is_not_worse_than_single(rng, key):
    X, _ = _blobs(rng, k=6, spread=1.2)
    one = fx.kernel_kmeans(X, 6, 0.3, key=key, n_init=1)
    many = fx.kernel_kmeans(X, 6, 0.3, key=key, n_init=8)
    assert float(many.objective) <= float(one.objective) + 1e-9


def test_jit_and_vmap_over_gamma(rng, key):
    X, _ = _blobs(rng)
    f = lambda g: fx.kernel_kmeans(X, 4, g, key=key, n_init=3).objective
    eager = np.array([float(f(g)) for g in (0.2, 0.5)])
    np.testing.assert_allclose(np.asarray(jax.jit(f)(0.2)), eager[0], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(jax.vmap(f)(jnp.array([0.2, 0.5]))), eager, rtol=1e-10)


def test_empty_cluster_is_reseeded(rng):
    X, _ = _blobs(rng, k=3)
    init = np.zeros((1, len(X)), int)  # every point in cluster 0: clusters 1, 2 empty
    res = fx.kernel_kmeans(X, 3, 0.5, init=init)
    assert np.all(np.asarray(res.sizes) > 0)


def test_refuses_what_does_not_fit(rng):
    X = rng.standard_normal((3000, 2))
    with pytest.raises(fx.FxspaceError, match=r"GiB.*O\(n²\).*subsample"):
        fx.kernel_kmeans(X, 5, 1.0, memory_limit_bytes=10_000_000)
    with pytest.raises(fx.FxspaceError, match="n_clusters"):
        fx.kernel_kmeans(X[:10], 11, 1.0)
    with pytest.raises(fx.FxspaceError, match="n_points, n_features"):
        fx.kernel_kmeans(X[:, 0], 2, 1.0)
