"""Issue 29 item 3 (part): the result vocabulary through equinox's public API only."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.results import RESULTS, result_code, result_messages, where_result


def test_no_private_equinox_import():
    import inspect

    import fxspace.results as R

    assert "equinox._enum" not in inspect.getsource(R)


def test_result_code_and_messages_cover_every_member():
    msgs = result_messages()
    assert msgs[int(result_code(RESULTS.successful))] == ""
    assert sorted(msgs) == list(range(len(msgs)))
    assert msgs[int(result_code(RESULTS.disconnected))].startswith("the neighbourhood graph")


def test_where_result_batched_matches_numpy_where_and_jits():
    pred = np.array([[True, False, True]])
    r = where_result(pred, RESULTS.successful, RESULTS.stalled)
    want = np.where(pred, int(result_code(RESULTS.successful)), int(result_code(RESULTS.stalled)))
    np.testing.assert_array_equal(np.asarray(result_code(r)), want)
    rj = jax.jit(lambda p: where_result(p, RESULTS.successful, RESULTS.stalled))(pred)
    np.testing.assert_array_equal(np.asarray(result_code(rj)), want)
    s = where_result(jnp.asarray(False), RESULTS.successful, RESULTS.stalled)
    assert s == RESULTS.stalled


def test_mds_result_carries_result_and_derived_converged():
    P = np.random.default_rng(0).normal(size=(8, 2))
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    res = fx.classical_mds(D)
    assert res.result == RESULTS.successful and bool(res.converged)
    bad = jax.jit(fx.classical_mds)(jnp.asarray(D).at[0, 1].set(jnp.nan))
    assert bad.result == RESULTS.nonfinite_input and not bool(bad.converged)


def test_iterative_records_derive_converged_from_result():
    """Issue 29.3: every iterative routine's record has ``.result`` and ``.stats``;
    ``converged`` is derived from ``result`` (a property), never a stored field."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(60, 2))
    key = jax.random.key(0)
    T = rng.normal(size=(10, 30, 3)).cumsum(0)
    model, km = fit = fx.fit_control_points(T, 3, key=key, n_init=2)
    records = [
        fx.fuzzy_cmeans(X, 3, key=key),
        fx.kernel_kmeans(X, 3, 0.5, key=key),
        fx.fused_lasso_solve(np.r_[np.zeros(10), np.ones(10)], 0.0, 0.5),
        fx.refine_control_points(T, model, steps=5),
        fit,
        fx.fit_scene(T, 3, boundaries=[0, 5, 9], key=key, n_init=2, fit_steps=3),
    ]
    for r in records:
        assert "converged" not in r._fields, type(r).__name__
        assert hasattr(r, "result") and hasattr(r, "stats"), type(r).__name__
    for r in records[:5]:
        assert bool(r.converged) == bool(r.result == RESULTS.successful), type(r).__name__
    sf = records[-1]
    assert len(sf.converged) == 2 and isinstance(sf.converged[0], bool)
    assert (sf.result == RESULTS.successful) == all(
        bool(k.result == RESULTS.successful) for k in sf.clusterings
    ) and all(sf.converged)
    assert fit.result is km.result and fit.model is model
    bad = fx.fuzzy_cmeans(np.r_[X, [[np.nan, 0.0]]], 3, key=key)
    assert bad.result == RESULTS.nonfinite_input and not bool(bad.converged)


def test_disconnected_geodesics_are_named_disconnected():
    """Issue 29.3: every declared RESULTS member is reachable — ``disconnected`` from MDS
    of the geodesics of a graph in two components (under jit; raised, with the fix,
    outside)."""
    rng = np.random.default_rng(0)
    P = np.r_[rng.normal(size=(6, 2)), rng.normal(size=(6, 2)) + 50]
    geo = fx.geodesic_distances(fx.epsilon_graph(fx.pairwise_distances(jnp.asarray(P)), 5.0))
    res = jax.jit(fx.classical_mds)(geo.distances)
    assert res.result == RESULTS.disconnected and not bool(res.converged)
    with pytest.raises(fx.DisconnectedGraphError, match="raise the threshold"):
        fx.classical_mds(geo.distances)
    nan = jax.jit(fx.classical_mds)(jnp.asarray(geo.distances).at[0, 1].set(jnp.nan))
    assert nan.result == RESULTS.nonfinite_input
