"""Issue 45: the truncated FCM a block of points at a time, here and on a Dask cluster:
the same numbers bit for bit, the same clustering as the one-loop solver, and errors
that name the fix."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.cluster import fuzzy_cmeans

_FIELDS = ("centers", "indices", "memberships", "objective", "num_steps")


def _blobs(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-8, 8, size=(12, 2))
    return centres[rng.integers(0, 12, n)] + rng.normal(scale=0.6, size=(n, 2))


def _same(a, b):
    for name in _FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)))
    assert a.result == b.result


@pytest.mark.slow
def test_blocks_reach_the_fixed_point_of_the_one_loop_solver():
    X = _blobs(1200)
    kw = {"nearest": 4, "key": jax.random.key(0), "tol": 1e-7, "max_steps": 1000}
    one = fuzzy_cmeans(X, 12, **kw)
    got = fuzzy_cmeans(X, 12, rows_per_task=500, chunk=256, **kw)
    assert one.converged and got.converged
    np.testing.assert_allclose(np.asarray(got.centers), np.asarray(one.centers), atol=1e-5)
    np.testing.assert_allclose(float(got.objective), float(one.objective), rtol=1e-7)
    np.testing.assert_array_equal(np.sort(np.asarray(got.indices), axis=1),
                                  np.sort(np.asarray(one.indices), axis=1))  # fmt: skip
    np.testing.assert_allclose(np.asarray(got.memberships).sum(axis=1), 1.0, rtol=1e-12)


@pytest.mark.slow
def test_all_centres_kept_in_blocks_is_plain_fcm():
    X = _blobs(300)
    v0 = fx.cluster.kmeanspp_init(jnp.asarray(X), 5, jax.random.key(1))
    dense = fuzzy_cmeans(X, 5, init_centers=v0, tol=1e-9, max_steps=300, check_every=1)
    got = fuzzy_cmeans(X, 5, nearest=5, init_centers=v0, tol=1e-9, max_steps=300,
                       rows_per_task=128)  # fmt: skip
    np.testing.assert_allclose(np.asarray(got.centers), np.asarray(dense.centers), atol=1e-6)


def test_blocks_repeat_bit_for_bit_and_report_bad_input():
    X = _blobs(500)
    kw = {"nearest": 3, "key": jax.random.key(2), "rows_per_task": 200, "max_steps": 20}
    _same(fuzzy_cmeans(X, 10, **kw), fuzzy_cmeans(X, 10, **kw))
    bad = X.copy()
    bad[5, 1] = np.nan
    res = fuzzy_cmeans(bad, 10, nearest=3, init_centers=X[:10], rows_per_task=256)
    assert res.result == fx.RESULTS.nonfinite_input
    assert np.isnan(np.asarray(res.centers)).all()
    with pytest.raises(fx.FxspaceError, match="x"):
        fuzzy_cmeans(bad, 10, nearest=3, init_centers=X[:10], rows_per_task=256, throw=True)


def test_block_options_name_the_fix():
    X = _blobs(200)
    key = jax.random.key(0)
    for bad in (0, -1, 2.5, "8", True):
        with pytest.raises(fx.FxspaceError, match="rows_per_task must be"):
            fuzzy_cmeans(X, 4, nearest=2, key=key, rows_per_task=bad)
    for name in ("rows_per_task", "client"):
        with pytest.raises(fx.FxspaceError, match=f"{name} applies to truncated.*nearest=p"):
            fuzzy_cmeans(X, 4, key=key, **{name: 64})
    with pytest.raises(fx.FxspaceError, match="n_clusters"):
        fuzzy_cmeans(X, 0, nearest=2, key=key, rows_per_task=64)
    with pytest.raises(fx.FxspaceError, match="outside jit"):
        jax.jit(lambda y: fuzzy_cmeans(y, 4, nearest=2, init_centers=y[:4],
                                       rows_per_task=64).centers)(X)  # fmt: skip


@pytest.mark.slow
def test_a_two_worker_local_cluster_gives_the_fcm_of_one_process():
    distributed = pytest.importorskip("dask.distributed")
    X = _blobs(4000)
    kw = {"nearest": 4, "key": jax.random.key(0), "rows_per_task": 900, "chunk": 300,
          "max_steps": 80}  # fmt: skip
    here = fuzzy_cmeans(X, 30, **kw)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=None, host="127.0.0.1") as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        there = fuzzy_cmeans(X, 30, client=client, **kw)
        left = client.run(lambda: len(__import__("fxspace.cluster._fcm_blocks",
                                                 fromlist=["_STATES"])._STATES))  # fmt: skip
    assert len(left) == 2 and set(left.values()) == {0}  # the blocks were dropped
    assert np.asarray(here.centers).dtype == np.float64  # the tests run in x64
    _same(here, there)
