"""Issue 45: the threshold sweep's host path (folded Floyd, components from the geodesics)
against the traced sweep, and the space at the chosen ε taking the sweep's embedding."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.distance import cdist

import fxspace as fx
from fxspace.expression import _space
from fxspace.expression._sweep import _components


def _curve(rng, n=150):
    s = np.sort(rng.random(n)) * 3 * np.pi
    X = np.c_[s * np.cos(s), s * np.sin(s), 0.05 * rng.standard_normal(n)]
    return jnp.asarray(cdist(X, X))


def test_host_sweep_equals_traced_sweep(rng):
    P = _curve(rng)
    th = fx.threshold_grid(P, 6) * np.r_[0.5, 1, 1, 1, 1, 1]  # the first ε disconnects it
    host = fx.threshold_sweep(P, th)
    traced = jax.jit(fx.threshold_sweep)(P, jnp.asarray(th))
    assert not bool(host.connected[0])
    for f in ("connected", "n_components", "mean_degree"):
        np.testing.assert_array_equal(np.asarray(getattr(host, f)), np.asarray(getattr(traced, f)))
    np.testing.assert_allclose(host.scores, traced.scores, rtol=1e-10, equal_nan=True)
    np.testing.assert_allclose(host.eigenvalues, traced.eigenvalues, rtol=1e-8, equal_nan=True)


def test_components_from_geodesics(rng):
    P = _curve(rng, 90)
    for eps in (0.2, 0.5, 1.0, 3.0):
        W = fx.epsilon_graph(P, eps)
        D = fx.floyd_warshall(W)
        assert int(_components(D)) == int(fx.connected_components(W)[0])


def test_space_takes_the_sweeps_embedding(rng):
    P = _curve(rng)
    sw = fx.threshold_sweep(P, fx.threshold_grid(P, 5))
    eps = fx.choose_threshold(sw, min_bridge_part=None)["threshold"]  # the highest r
    key = (float(eps), 2, "auto", "auto")
    assert _space._recall(P, key) is not None  # the best-scoring ε is kept ...
    es = fx.expression_space(None, eps, pairwise=P)
    fresh = fx.expression_space(None, eps, pairwise=jnp.array(P))  # ... for P only
    np.testing.assert_array_equal(es.geodesics.distances, fresh.geodesics.distances)
    np.testing.assert_array_equal(es.geodesics.next_hop, fresh.geodesics.next_hop)
    np.testing.assert_array_equal(es.embedding, fresh.embedding)
    assert float(es.score) == float(fresh.score)
    assert _space._recall(P, (float(eps) * 2, 2, "auto", "auto")) is None


def test_check_connected_still_names_the_components(rng):
    P = _curve(rng, 60)
    with pytest.raises(fx.errors.DisconnectedGraphError, match="connected components"):
        fx.check_connected(fx.epsilon_graph(P, 1e-6), P)
    fx.check_connected(fx.epsilon_graph(P, float(fx.connecting_threshold(P))), P)
