"""Issue 29 item 3 (part): the result vocabulary through equinox's public API only."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

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
