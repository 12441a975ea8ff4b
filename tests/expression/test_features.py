import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.distance import cdist, pdist, squareform
from scipy.spatial.transform import Rotation

import fxspace as fx


def _rigid(rng, X):
    R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    t = rng.standard_normal(3) * 100
    return X @ R.T + t


def test_features_match_pdist(rng):
    X = rng.standard_normal((5, 7, 3))
    F = np.asarray(fx.distance_features(X))
    G = np.asarray(fx.distance_features(X, full_matrix=False))
    assert F.shape == G.shape == (5, 21)
    for t in range(5):
        np.testing.assert_allclose(G[t], pdist(X[t]), rtol=1e-6)
        np.testing.assert_allclose(F[t], np.sqrt(2) * pdist(X[t]), rtol=1e-6)


def test_long_sequences_in_blocks_match_pdist_nan_jit_vmap_grad(rng):
    """Past one block of frames (`_FRAMES_PER_BLOCK`) the features come in blocks: the
    same numbers as pdist, NaN kept, under jit / vmap / grad."""
    from fxspace.expression._features import _FRAMES_PER_BLOCK

    T = 2 * _FRAMES_PER_BLOCK + 37  # a ragged last block
    X = rng.standard_normal((T, 6, 3)) * 30
    X[T - 5, 2] = np.nan  # a missing marker in the padded last block
    F = np.asarray(fx.distance_features(X))
    ref = np.sqrt(2) * np.stack([pdist(x) for x in X])
    assert F.shape == (T, 15)
    np.testing.assert_allclose(F, ref, rtol=1e-5)  # NaN where the reference has NaN
    np.testing.assert_array_equal(np.asarray(jax.jit(fx.distance_features)(X)), F)
    V = np.asarray(jax.vmap(fx.distance_features)(X[None].repeat(2, 0)))
    np.testing.assert_array_equal(V[1], F)
    g = jax.grad(lambda x: jnp.sum(fx.distance_features(x)))(jnp.asarray(X[: T - 10]))
    assert g.shape == (T - 10, 6, 3) and np.all(np.isfinite(np.asarray(g)))


def test_state_distance_is_the_papers_full_matrix_distance(rng):
    """Kim & Jung §2.2: the state is the whole M×M distance matrix laid out as a vector;
    the straight-line distance between two states is the Frobenius distance."""
    X = rng.standard_normal((9, 6, 3)) * 40
    full = np.stack([squareform(pdist(x)) for x in X]).reshape(len(X), -1)
    P = np.asarray(fx.pairwise_distances(fx.distance_features(X)))
    np.testing.assert_allclose(P, cdist(full, full), rtol=1e-5, atol=1e-3)
    with jax.enable_x64(True):
        P64 = np.asarray(fx.pairwise_distances(fx.distance_features(X.astype(np.float64))))
    np.testing.assert_allclose(P64, cdist(full, full), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("scale", [1e19, 1e-25])
def test_extreme_float32_coordinates(rng, scale):
    """Differences are scaled before squaring: no inf at 1e19, no zeros at 1e-25."""
    X = rng.standard_normal((5, 4, 3))
    F = np.asarray(fx.distance_features((X * scale).astype(np.float32)))
    ref = np.sqrt(2) * np.stack([pdist(x) for x in X]) * scale
    assert F.dtype == np.float32 and np.isfinite(F).all() and (F > 0).all()
    np.testing.assert_allclose(F, ref, rtol=1e-5)
    P = np.asarray(fx.pairwise_distances(F))
    assert np.isfinite(P).all()
    np.testing.assert_allclose(P, cdist(ref, ref), rtol=1e-4, atol=1e-6 * ref.max())


def test_features_rigid_invariant(rng):
    X = rng.standard_normal((4, 10, 3)) * 50
    Y = np.stack([_rigid(rng, x) for x in X])
    np.testing.assert_allclose(fx.distance_features(X), fx.distance_features(Y), rtol=1e-9)


def test_pairwise_matches_cdist_and_jit(rng):
    F = rng.standard_normal((30, 12)) * 40 + 500
    P = fx.pairwise_distances(F)
    np.testing.assert_allclose(P, cdist(F, F), rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(jax.jit(fx.pairwise_distances)(F), P, rtol=1e-12)
    assert np.all(np.diag(np.asarray(P)) == 0)


def test_feature_grad_finite(rng):
    X = jnp.asarray(rng.standard_normal((3, 4, 3)))
    X = X.at[0, 1].set(X[0, 0])  # coincident markers: gradient must stay finite
    g = jax.grad(lambda x: jnp.sum(fx.pairwise_distances(fx.distance_features(x))))(X)
    assert np.all(np.isfinite(g))


def test_bad_shapes():
    with pytest.raises(ValueError, match="positions"):
        fx.distance_features(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="features"):
        fx.pairwise_distances(np.zeros(3))


def test_clean_frames_drop_and_raise(rng):
    X = rng.standard_normal((6, 5, 3))
    X[2, 1, 0] = np.nan
    X[4] = np.nan
    with pytest.warns(UserWarning, match="dropped 2 of 6"):
        Y, kept = fx.clean_frames(X)
    assert Y.shape == (4, 5, 3)
    np.testing.assert_array_equal(kept, [0, 1, 3, 5])
    with pytest.raises(ValueError, match="2 of 6 frames"):
        fx.clean_frames(X, policy="raise")
