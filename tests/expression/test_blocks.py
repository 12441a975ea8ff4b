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


def _plain_features(pos):
    """The features summed the plain way: ``√(dx² + dy² + dz²)`` per pair, then weighted."""
    from fxspace.expression._features import PAIR_WEIGHT

    x = np.asarray(pos, pos.dtype if pos.dtype.kind == "f" else np.float64)
    iu, ju = np.triu_indices(x.shape[1], 1)
    acc = np.zeros((len(x), len(iu)), x.dtype)
    for c in range(3):
        acc += (x[:, iu, c] - x[:, ju, c]) ** 2
    return np.sqrt(acc) * x.dtype.type(PAIR_WEIGHT)


@pytest.mark.parametrize("block", [1, 100, 300])
def test_block_features_are_the_plain_sums_bit_for_bit(block):
    from fxspace.expression._blocks import _block_features

    pos = _positions(333).astype(np.float32)
    for p in (pos, np.round(pos * 10).astype(np.int32)):
        got = _block_features(p, np.arange(len(p)), block)
        np.testing.assert_array_equal(got, _plain_features(p))


def _plain_neighbours(F, Z, num, k):
    """Each frame's k nearest among its num nearest in Z: the query in frame order, each
    pair's distance summed alone, ties in the order of the projection's nearest."""
    from scipy.spatial import cKDTree

    _, ii = cKDTree(Z).query(Z, k=num + 1)
    out_c, out_d = [], []
    for i, row in enumerate(ii):
        c = row[row != i][:num] if (row == i).any() else row[:num]
        d = np.array([np.sqrt(((F[j] - F[i]) ** 2).sum()) for j in c], F.dtype)
        o = np.argsort(d, kind="stable")[:k]
        out_c.append(c[o])
        out_d.append(d[o])
    return np.array(out_c), np.array(out_d)


@pytest.mark.parametrize("num", [30, 299])
def test_leaf_ordered_neighbours_equal_the_plain_search(tmp_path, num):
    """Near-duplicates (0.3 mm noise) and exact duplicates (ties): the leaf-ordered, batched
    search gives each frame what the plain per-frame search gives, bit for bit; with every
    frame a candidate it is the brute-force exact k-NN."""
    from fxspace.expression import _blocks

    rng = np.random.default_rng(1)
    base = _positions(100, seed=3).astype(np.float32)
    pos = np.concatenate([base, base[rng.integers(0, 100, 150)], base[:50]])
    pos[100:250] += rng.normal(0, 0.3, pos[100:250].shape).astype(np.float32)
    F = _plain_features(pos)
    path = str(tmp_path / "f.npy")
    np.save(path, F)
    Z = np.ascontiguousarray((F - F.mean(axis=0)) @ np.linalg.svd(F - F.mean(axis=0))[2][:8].T)
    want_c, want_d = _plain_neighbours(F, Z, num, 6)
    got = [_blocks._neighbours(path, Z, s, min(s + 70, len(F)), num, 6) for s in range(0, 300, 70)]
    np.testing.assert_array_equal(np.concatenate([c for c, _ in got]), want_c)
    np.testing.assert_array_equal(np.concatenate([d for _, d in got]), want_d)
    if num == 299:  # every frame a candidate: the exact k nearest distances
        D = np.sqrt(((F[:, None, :] - F[None, :, :]) ** 2).sum(axis=2))
        np.fill_diagonal(D, np.inf)
        np.testing.assert_array_equal(want_d, np.sort(D, axis=1)[:, :6])


def test_the_approximate_candidate_search_is_said_checked_and_exact_at_zero():
    """``search_eps``: the candidates from the k-d tree's approximate search (the default,
    0.5) or its exact one (0); the k kept are chosen by exact distances either way. On a
    smooth take (every frame moving, as a capture) both find every exact neighbour; on
    the synthetic face's held poses (neighbours decided by noise) both are as close; a
    negative value is refused by name."""
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 60.0, 3000)[:, None, None]
    base = rng.normal(0, 50, (1, 14, 3))
    amp, freq = rng.normal(0, 5, (14, 3)), rng.uniform(0.05, 0.5, (14, 3))
    pos = base + amp * np.sin(freq * t + rng.uniform(0, 2 * np.pi, (14, 3)))
    F = np.asarray(fx.distance_features(pos))
    for eps in (0.0, 0.5):
        g = neighbourhood_graph_blocks(pos, k=8, search_eps=eps)
        assert fx.expression.knn_recall(F, g, k=8, sample=300) == 1.0
    held = _positions(1500, seed=2)
    Fh = np.asarray(fx.distance_features(held))
    r = [fx.expression.knn_quality(Fh, neighbourhood_graph_blocks(held, k=8, search_eps=e),
                                   k=8, sample=300).distance_ratio for e in (0.0, 0.5)]  # fmt: skip
    assert r[1] <= r[0] * 1.01, r
    with pytest.raises(fx.FxspaceError, match="search_eps"):
        neighbourhood_graph_blocks(pos, k=8, search_eps=-1.0)
