"""Hirose & Higuchi as printed (issue 31.3): the control points' labels are kernel k-means'
to the end — on a dense segment (subset restarts) the final labels are a fixed point of one
more kernel k-means step on every vertex; the hybrid (Euclidean k-means finishing the
labels) is the named option ``method="hybrid"``."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx


def _segment(rng, T=30, N=360):
    t = np.linspace(0, 1, T)[:, None, None]
    g = rng.integers(0, 5, N)  # five groups of vertices moving alike, plus noise
    f = (1.0 + g)[None, :, None]
    ph = (0.15 * g)[None, :, None]
    amp = rng.uniform(0.05, 0.15, (1, N, 1))
    X = rng.normal(size=(1, N, 3)) + amp * np.sin(2 * np.pi * (f * t + ph))
    return X + 0.02 * rng.normal(size=(T, N, 3))


def _features(X):
    """The scaled residual trajectories, written out from the paper's definition."""
    R = np.asarray(fx.residual_trajectories(jnp.asarray(X)))[1:-1]
    F = np.moveaxis(R, 1, 0).reshape(X.shape[1], -1)
    return F / np.sqrt(np.mean(np.sum(F**2, axis=1)))


def _one_kernel_kmeans_step(F, labels, gamma, c):
    """Lloyd's step of kernel k-means in feature space, in numpy (independent of fxspace):
    ``d_ik = K_ii − 2 mean_{j∈k} K_ij + mean_{j,l∈k} K_jl``."""
    sq = np.sum((F[:, None] - F[None]) ** 2, axis=-1)
    K = np.exp(-gamma * sq)
    H = np.eye(c)[labels]
    n = H.sum(0)
    KH = K @ H / n
    within = np.einsum("ik,ij,jk->k", H, K, H) / n**2
    d = np.diag(K)[:, None] - 2 * KH + within[None]
    return np.argmin(d, axis=1)


def test_default_labels_are_a_kernel_kmeans_fixed_point_on_every_vertex():
    X = _segment(np.random.default_rng(0))
    F = _features(X)
    idx = np.linspace(0, X.shape[1] - 1, 100).round().astype(int)
    gamma = float(fx.median_gamma(jnp.asarray(F[idx])))
    model, km = fx.fit_control_points(
        jnp.asarray(X), 5, key=jax.random.key(1), n_init=4, max_points=100
    )
    labels = np.asarray(model.labels)
    assert labels.shape == (X.shape[1],) and bool(km.converged)
    np.testing.assert_array_equal(np.asarray(km.labels), labels)
    np.testing.assert_array_equal(_one_kernel_kmeans_step(F, labels, gamma, 5), labels)


def test_hybrid_is_a_named_option_and_bad_methods_are_refused():
    X = jnp.asarray(_segment(np.random.default_rng(2)))
    m_k, _ = fx.fit_control_points(X, 5, key=jax.random.key(1), n_init=4, max_points=100)
    m_h, km_h = fx.fit_control_points(
        X, 5, key=jax.random.key(1), n_init=4, max_points=100, method="hybrid"
    )
    assert km_h.labels.shape == (100,)  # the hybrid reports the subset's clustering
    # on well-separated groups both find the same partition (up to label names)
    pairs = set(zip(np.asarray(m_k.labels).tolist(), np.asarray(m_h.labels).tolist(), strict=True))
    assert len(pairs) == 5
    with pytest.raises(fx.errors.FxspaceError, match="method"):
        fx.fit_control_points(X, 5, method="euclid")
