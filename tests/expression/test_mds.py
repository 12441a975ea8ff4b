import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.distance import cdist
from scipy.stats import pearsonr

import fxspace as fx
from fxspace.expression._mds import double_centre
from tests.helpers import check_grad


def _procrustes_err(Y, X):
    """Residual after the best orthogonal alignment (MDS is unique up to rotation/reflection)."""
    Yc, Xc = Y - Y.mean(0), X - X.mean(0)
    U, _, Vt = np.linalg.svd(Yc.T @ Xc)
    return np.abs(Yc @ (U @ Vt) - Xc).max()


@pytest.mark.parametrize("method", ["eigh", "lobpcg"])
def test_exact_2d_configuration(rng, method):
    X = rng.standard_normal((500, 2)) * np.array([5.0, 2.0])
    res = fx.classical_mds(cdist(X, X), dim=2, method=method)
    assert _procrustes_err(np.asarray(res.embedding), X) < 1e-6


@pytest.mark.parametrize("method", ["eigh", "lobpcg"])
def test_matches_numpy_eigh(rng, method):
    X = rng.standard_normal((450, 4)) * np.array([4.0, 2.0, 1.0, 0.5])
    D = cdist(X, X) + 0.1 * rng.random((450, 450))
    D = (D + D.T) / 2
    np.fill_diagonal(D, 0)
    J = np.eye(450) - 1 / 450
    B = -0.5 * J @ (D**2) @ J
    np.testing.assert_allclose(double_centre(jnp.asarray(D)), B, atol=1e-9)
    w, V = np.linalg.eigh(B)
    res = fx.classical_mds(D, dim=3, method=method)
    np.testing.assert_allclose(res.eigenvalues, w[::-1][:3], rtol=1e-7)
    ref = V[:, ::-1][:, :3] * np.sqrt(w[::-1][:3])
    Y = np.asarray(res.embedding)
    for a in range(3):  # up to sign
        s = np.sign(Y[:, a] @ ref[:, a])
        np.testing.assert_allclose(Y[:, a], s * ref[:, a], atol=1e-6)


def test_pearson_matches_scipy(rng):
    X = rng.standard_normal((60, 3))
    D = cdist(X, X) + rng.random((60, 60))
    D = (D + D.T) / 2
    Y = rng.standard_normal((60, 2))
    iu = np.triu_indices(60, 1)
    ref = pearsonr(D[iu], cdist(Y, Y)[iu])[0]
    np.testing.assert_allclose(fx.pearson_score(D, Y), ref, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(fx.pearson_score)(D, Y), ref, rtol=1e-12)


def test_mds_grad_matches_dense_eigh_autodiff(rng):
    X = rng.standard_normal((40, 3)) * np.array([3.0, 2.0, 1.0])
    D = cdist(X, X) + 0.05 * rng.random((40, 40))
    D = jnp.asarray((D + D.T) / 2).at[jnp.diag_indices(40)].set(0)
    wts = jnp.asarray(rng.standard_normal((40, 2)))

    def ours(D):
        return jnp.sum(fx.classical_mds(D, 2, method="eigh").embedding ** 2 * wts)

    def ref(D):
        w, V = jnp.linalg.eigh(double_centre(D))
        return jnp.sum((V[:, ::-1][:, :2] * jnp.sqrt(w[::-1][:2])[None, :]) ** 2 * wts)

    np.testing.assert_allclose(jax.grad(ours)(D), jax.grad(ref)(D), atol=1e-9)


def test_chain_grad_wrt_markers(rng):
    """features → graph → geodesic → MDS → r is differentiable w.r.t. marker positions."""
    base = rng.standard_normal((1, 6, 3))
    t = np.linspace(0, 1, 24)[:, None, None]
    X = base + t * rng.standard_normal((1, 6, 3)) + 0.05 * rng.standard_normal((24, 6, 3))

    def score(x):
        P = fx.pairwise_distances(fx.distance_features(x))
        D = fx.floyd_warshall(fx.epsilon_graph(P, 2.0))
        return fx.pearson_score(D, fx.classical_mds(D, 2).embedding)

    assert np.isfinite(score(X))
    check_grad(score, jnp.asarray(X), rng, eps=1e-6, rtol=1e-4)


def test_vmap_mds(rng):
    X = rng.standard_normal((3, 30, 2))
    Ds = jnp.asarray(np.stack([cdist(x, x) for x in X]))
    res = jax.vmap(lambda d: fx.classical_mds(d, 2))(Ds)
    for k in range(3):
        np.testing.assert_allclose(
            res.embedding[k], fx.classical_mds(Ds[k], 2).embedding, atol=1e-10
        )


def test_bad_input():
    with pytest.raises(ValueError, match="dim"):
        fx.classical_mds(np.zeros((3, 3)), dim=5)
    with pytest.raises(ValueError, match="square"):
        fx.classical_mds(np.zeros((3, 2)))
