"""Property-based tests (issue 10): metric properties of the distances and rigid-motion
invariance of the features, on inputs hypothesis draws."""

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

import fxspace as fx

SETTINGS = settings(max_examples=40, deadline=None)

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@SETTINGS
@given(
    F=st.tuples(st.integers(2, 12), st.integers(1, 6)).flatmap(
        lambda shape: arrays(np.float64, shape, elements=finite)
    ),
    dtype=st.sampled_from([np.float32, np.float64]),
)
def test_pairwise_distances_are_a_metric(F, dtype):
    F = F.astype(dtype)
    P = np.asarray(fx.pairwise_distances(jnp.asarray(F)), np.float64)
    n = len(F)
    ref = cdist(F.astype(np.float64), F.astype(np.float64))
    scale = max(1.0, float(np.abs(F).max()))
    # float32 goes through float64 blocks (rounding only); float64 uses the Gram expansion,
    # whose absolute error near coincident rows is ~sqrt(eps64)·scale
    tol = (1e-5 if dtype == np.float32 else 1e-7) * scale
    assert np.all(np.diag(P) == 0)  # identity
    np.testing.assert_array_equal(P, P.T)  # symmetry
    assert np.all(P >= 0)  # non-negativity
    np.testing.assert_allclose(P, ref, rtol=1e-5, atol=tol)  # against scipy
    # triangle inequality on every triple
    tri = P[:, None, :] <= P[:, :, None] + P[None, :, :] + 2 * tol
    assert tri.all(), n


@st.composite
def frames_and_motion(draw):
    T = draw(st.integers(1, 4))
    M = draw(st.integers(2, 8))
    X = np.asarray(draw(arrays(np.float64, (T, M, 3), elements=finite)))
    quats = draw(arrays(np.float64, (T, 4), elements=st.floats(-1, 1)))
    quats[np.linalg.norm(quats, axis=1) < 1e-3] = [0, 0, 0, 1]
    shift = draw(arrays(np.float64, (T, 3), elements=finite))
    return X, quats, shift


@SETTINGS
@given(frames_and_motion())
def test_features_invariant_to_rigid_motion(args):
    X, quats, shift = args
    R = Rotation.from_quat(quats).as_matrix()  # one rigid motion per frame
    Y = np.einsum("tij,tmj->tmi", R, X) + shift[:, None, :]
    F = np.asarray(fx.distance_features(X))
    G = np.asarray(fx.distance_features(Y))
    scale = max(1.0, float(np.abs(X).max()), float(np.abs(shift).max()))
    np.testing.assert_allclose(G, F, atol=1e-9 * scale)
    # and the features are the pairwise marker distances (scipy's pdist order), each
    # weighted by sqrt(2) (the full distance matrix, Kim & Jung)
    from scipy.spatial.distance import pdist

    for t in range(len(X)):
        np.testing.assert_allclose(F[t], np.sqrt(2) * pdist(X[t]), atol=2e-9 * scale)


@SETTINGS
@given(
    X=arrays(np.float64, (6, 4, 3), elements=finite),
    m=st.integers(0, 3),
    t=st.integers(0, 5),
)
def test_missing_marker_propagates_to_exactly_its_pairs(X, m, t):
    X = X.copy()
    X[t, m] = np.nan
    F = np.asarray(fx.distance_features(X))
    i, j = np.triu_indices(4, 1)
    hit = (i == m) | (j == m)
    assert np.isnan(F[t, hit]).all() and np.isfinite(F[t, ~hit]).all()
    others = np.arange(6) != t
    assert np.isfinite(F[others]).all()
