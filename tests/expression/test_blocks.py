"""Issue 45: the k-NN graph a block at a time (features on disk), here and on a Dask
cluster: the same graph, and the exact k nearest where the search is exact."""

from __future__ import annotations

import numpy as np
import pytest

import fxspace as fx
from fxspace.expression import neighbourhood_graph_blocks
from fxspace.synthetic import synthetic_face


def _positions(T=1200, seed=0):
    return np.asarray(synthetic_face(n_markers=12, n_frames=T, seed=seed).sequence.positions)


def test_blocks_equal_the_exact_graph_when_every_candidate_is_kept():
    pos = _positions(600)
    F = np.asarray(fx.distance_features(pos))
    exact = fx.neighbourhood_graph(F, k=6, reduce_dim=None)
    got = neighbourhood_graph_blocks(pos, k=6, candidates=599, rows_per_task=128, block=100)
    a, b = fx.expression.to_scipy(got), fx.expression.to_scipy(exact)
    assert (a != 0).toarray().tolist() == (b != 0).toarray().tolist()
    np.testing.assert_allclose(a.toarray(), b.toarray(), rtol=1e-5)
    assert fx.expression.knn_recall(F, got, k=6, sample=200) == 1.0


def test_blocks_do_not_depend_on_the_block_sizes(tmp_path):
    pos = _positions()
    g1 = neighbourhood_graph_blocks(pos, k=8, rows_per_task=1200, block=2048)
    g2 = neighbourhood_graph_blocks(pos, k=8, rows_per_task=257, block=64,
                                    store=tmp_path / "f.npy")  # fmt: skip
    np.testing.assert_array_equal(np.asarray(g1.indices), np.asarray(g2.indices))
    np.testing.assert_array_equal(np.asarray(g1.weights), np.asarray(g2.weights))
    F = np.load(tmp_path / "f.npy")
    np.testing.assert_allclose(F, np.asarray(fx.distance_features(pos)), rtol=1e-6)


def test_blocks_refuse_bad_input():
    pos = _positions(200)
    with pytest.raises(fx.FxspaceError, match="positions must be"):
        neighbourhood_graph_blocks(pos[:, :, :2], k=4)
    bad = pos.copy()
    bad[3, 2] = np.nan
    with pytest.raises(fx.FxspaceError, match="NaN"):
        neighbourhood_graph_blocks(bad, k=4)
    with pytest.raises(fx.FxspaceError, match="k"):
        neighbourhood_graph_blocks(pos, k=0)


def test_blocks_never_write_over_a_file(tmp_path):
    mine = tmp_path / "mine.npy"
    mine.write_bytes(b"the user's")
    link = tmp_path / "link.npy"
    link.symlink_to(mine)
    for store in (mine, link):
        with pytest.raises(fx.FxspaceError, match="already exists"):
            neighbourhood_graph_blocks(_positions(200), k=4, store=store)
    assert mine.read_bytes() == b"the user's"


@pytest.mark.slow
def test_a_two_worker_local_cluster_gives_the_graph_of_one_process():
    distributed = pytest.importorskip("dask.distributed")
    pos = _positions(3000)
    here = neighbourhood_graph_blocks(pos, k=8, rows_per_task=700)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=None, host="127.0.0.1") as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        there = neighbourhood_graph_blocks(pos, k=8, rows_per_task=700, client=client)
        ran = client.run(lambda: 1)
    assert len(ran) == 2
    np.testing.assert_array_equal(np.asarray(here.indices), np.asarray(there.indices))
    np.testing.assert_array_equal(np.asarray(here.weights), np.asarray(there.weights))
