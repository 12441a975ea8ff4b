"""Issue 45: max-min landmarks in rounds (``batch``), here and on a Dask cluster: the
same landmarks and rows, known answers of the rounds, and errors that name the fix."""

from __future__ import annotations

import numpy as np
import pytest

import fxspace as fx
from fxspace.expression import _landmark_rounds, farthest_point_landmarks, graph_from_dense
from fxspace.expression._landmark_rounds import lower_bound, round_picks
from fxspace.synthetic import synthetic_face


def _graph(T=1500):
    pos = np.asarray(synthetic_face(n_markers=12, n_frames=T, seed=0).sequence.positions)
    return fx.expression.neighbourhood_graph_blocks(pos, k=8)


def _path(n=40):
    """A path graph 0 – 1 – … – n−1 with unit edges: the geodesic is |i − j|."""
    W = np.full((n, n), np.inf)
    i = np.arange(n - 1)
    W[i, i + 1] = W[i + 1, i] = 1.0
    return graph_from_dense(W)


def _same(a, b):
    np.testing.assert_array_equal(np.asarray(a.landmarks), np.asarray(b.landmarks))
    np.testing.assert_array_equal(np.asarray(a.distances), np.asarray(b.distances))


def test_batch_one_is_the_sequential_result():
    g = _graph()
    _same(farthest_point_landmarks(g, 24, batch=1), farthest_point_landmarks(g, 24))


def test_rounds_start_with_exact_max_min_and_pick_distinct_frames():
    g = _graph()
    seq = farthest_point_landmarks(g, 30)
    got = farthest_point_landmarks(g, 30, batch=8)
    lm = np.asarray(got.landmarks)
    np.testing.assert_array_equal(lm[:8], np.asarray(seq.landmarks)[:8])
    assert len(set(lm.tolist())) == 30
    ref = fx.landmark_geodesics(g, lm, method="dijkstra")
    np.testing.assert_array_equal(np.asarray(got.distances), np.asarray(ref.distances))


def test_on_a_path_the_ends_come_first_and_rounds_are_exact():
    g = _path(41)
    seq = farthest_point_landmarks(g, 9)
    assert np.asarray(seq.landmarks)[:3].tolist() == [40, 0, 20]
    got = farthest_point_landmarks(g, 9, batch=3)
    assert np.asarray(got.landmarks)[:2].tolist() == [40, 0]
    # on a path the lower bound from an end is the geodesic: the rounds are max-min
    _same(got, seq)


def test_the_lower_bound_never_exceeds_the_geodesic():
    g = _graph(800)
    geo = farthest_point_landmarks(g, 12)
    rows = np.asarray(geo.distances, np.float64)
    for b in (0, 17, 399, 799):
        true = np.asarray(fx.landmark_geodesics(g, [b], method="dijkstra").distances[0])
        lb = lower_bound(rows, b)
        assert lb[b] == 0
        assert np.all(lb <= true * (1 + 1e-6) + 1e-6)
        assert lb.max() > 0.5 * true.max()  # and is not vacuous


def _eager_picks(mind, bound, taken, count, n):
    """A round's picks as the rounds were first written: the whole estimate each pick."""
    est, new = mind.copy(), []
    for _ in range(count):
        nxt = int(np.argmax(est))
        if est[nxt] == 0:
            nxt = next(i for i in range(n) if i not in taken and i not in new)
        new.append(nxt)
        est = np.minimum(est, lower_bound(bound, nxt))
        est[nxt] = 0
    return new


@pytest.mark.parametrize("top", [4096, 3])
def test_a_rounds_lazy_picks_are_the_whole_estimates_argmax(monkeypatch, top):
    """`round_picks` estimates frames only until no later one can win: the same picks
    as the T-wide estimate (ties to the lower frame as `np.argmax`), also where the
    ranked top runs out (``top`` = 3) and where every frame is taken or tied at 0."""
    monkeypatch.setattr(_landmark_rounds, "_TOP", top)
    monkeypatch.setattr(_landmark_rounds, "_SCAN", 4)
    rng = np.random.default_rng(1)
    for _ in range(150):
        T, K = int(rng.integers(3, 400)), int(rng.integers(1, 6))
        rows = np.round(rng.random((K, T)) * rng.integers(1, 5)).astype(np.float32)  # ties
        taken = set(rng.choice(T, min(K, T - 1), replace=False).tolist())
        mind = rows.min(axis=0)
        mind[list(taken)] = 0
        count = int(min(8, T - len(taken)))
        assert round_picks(mind, rows, taken, count, T) == _eager_picks(mind, rows, taken,
                                                                         count, T)
    g = _graph(800)  # a real graph's rows
    rows = np.asarray(farthest_point_landmarks(g, 12).distances, np.float32)
    mind = rows.min(axis=0)
    assert round_picks(mind, rows, set(), 8, 800) == _eager_picks(mind, rows, set(), 8, 800)


def test_more_landmarks_than_frames_asked_in_rounds():
    g = _path(6)
    got = farthest_point_landmarks(g, 6, batch=4)
    assert sorted(np.asarray(got.landmarks).tolist()) == list(range(6))


def test_rounds_refuse_bad_options():
    g = _path(10)
    for bad in (0, -2, 1.5, "4", True):
        with pytest.raises(fx.FxspaceError, match="batch must be an int"):
            farthest_point_landmarks(g, 4, batch=bad)
    with pytest.raises(fx.FxspaceError, match="pass batch too"):
        farthest_point_landmarks(g, 4, client=object())
    with pytest.raises(fx.FxspaceError, match="method='dijkstra'"):
        farthest_point_landmarks(g, 4, method="relax", batch=2, client=object())


@pytest.mark.slow
def test_a_two_worker_local_cluster_gives_the_landmarks_of_one_process():
    distributed = pytest.importorskip("dask.distributed")
    g = _graph(3000)
    here = farthest_point_landmarks(g, 40, batch=8)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=None, host="127.0.0.1") as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        there = farthest_point_landmarks(g, 40, batch=8, client=client)
        ran = client.run(lambda: 1)
    assert len(ran) == 2
    _same(here, there)
