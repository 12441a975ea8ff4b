"""Segments padded to frame buckets (issue 24: compile once): the clustering is the one of the
unpadded features, and segments of nearby lengths share their compiled programs."""

import jax
import jax.numpy as jnp
import numpy as np

import fxspace as fx
from fxspace.cluster import kernel_kmeans
from fxspace.controlpoints import _model


def _segment(rng, T, N=120):
    t = np.linspace(0, 1, T)[:, None, None]
    f = rng.uniform(1, 3, (1, N, 1))
    ph = rng.uniform(size=(1, N, 1))
    return rng.normal(size=(1, N, 3)) + 0.1 * np.sin(2 * np.pi * (f * t + ph))


def test_frame_bucket_bounds_padding_and_counts_sizes():
    sizes = [_model.frame_bucket(n) for n in range(3, 2000)]
    n = np.arange(3, 2000)
    b = np.asarray(sizes)
    assert np.all(b >= n) and np.all(b <= np.maximum(1.25 * n, n + 8))
    assert len(set(sizes)) < 45  # a few sizes per octave, not one per length
    assert _model.frame_bucket(64) == 64 and _model.frame_bucket(65) == 80


def test_padded_features_cluster_like_the_unpadded_ones():
    rng = np.random.default_rng(0)
    X = jnp.asarray(_segment(rng, 37))
    key = jax.random.key(3)
    # the unpadded features, written out from the method's definition
    R = np.asarray(fx.residual_trajectories(X))[1:-1]
    F = np.moveaxis(R, 1, 0).reshape(X.shape[1], -1)
    F = F / np.sqrt(np.mean(np.sum(F**2, axis=1)))
    ref = kernel_kmeans(jnp.asarray(F), 6, key=key, n_init=3)
    model, km = fx.fit_control_points(X, 6, key=key, n_init=3, max_points=None)
    np.testing.assert_array_equal(km.labels, ref.labels)
    np.testing.assert_array_equal(model.labels, ref.labels)
    assert model.controls.shape == (6, 37, 3)
    Fp = _model._features(_model._pad_frames(np.asarray(X), 48), jnp.asarray(37, jnp.int32))
    assert Fp.shape == (X.shape[1], 3 * 48)
    np.testing.assert_allclose(np.asarray(Fp)[:, 3 : 3 * 36], F, atol=1e-12)
    assert not np.any(np.asarray(Fp)[:, 3 * 36 :])  # the padding: exact zeros


def test_nearby_lengths_share_their_programs():
    rng = np.random.default_rng(1)
    before = _model._features._cache_size()
    for T in (41, 43, 47):  # one bucket (48)
        fx.fit_control_points(_segment(rng, T), 5, key=jax.random.key(0), n_init=2, max_points=None)
    assert _model._features._cache_size() - before <= 1
