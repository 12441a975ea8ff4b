"""`NeighbourGraph.steps()` (`fxspace.expression._paths.graph_steps`): the edges that are
shortest paths, against scipy's all-pairs Dijkstra (an edge is a step iff no path is
strictly shorter: exact ties keep it)."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from fxspace.expression import NeighbourGraph, graph_from_dense, to_scipy


def _reference(g: NeighbourGraph):
    """``(i, j, w)`` of the edges i < j whose weight is the all-pairs shortest distance."""
    csr = to_scipy(g)
    D = dijkstra(csr, directed=True)
    coo = csr.tocoo()
    up = coo.row < coo.col
    i, j, w = coo.row[up].astype(np.int64), coo.col[up].astype(np.int64), coo.data[up]
    o = np.lexsort((j, i))
    i, j, w = i[o], j[o], w[o].astype(np.float64)
    keep = D[i, j] >= w
    return i[keep], j[keep], w[keep]


def _check(g: NeighbourGraph):
    i, j, w = g.steps()
    ri, rj, rw = _reference(g)
    assert i.dtype == j.dtype == np.int64 and w.dtype == np.float64
    np.testing.assert_array_equal(i, ri)
    np.testing.assert_array_equal(j, rj)
    np.testing.assert_array_equal(w, rw)
    return i, j, w


def _random_dense(rng, n, density, dtype, ties=False):
    """A symmetric non-metric graph: random weights on random pairs (``inf`` = none)."""
    W = rng.integers(1, 6, (n, n)) * 0.25 if ties else rng.random((n, n)) ** 2 + 0.01
    W = np.where(rng.random((n, n)) < density, W, np.inf)
    W = np.minimum(W, W.T).astype(dtype)
    np.fill_diagonal(W, 0)
    return W


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("ties", [False, True])
def test_steps_equal_all_pairs_dijkstra(dtype, ties):
    rng = np.random.default_rng(3)
    for n, density in [(12, 0.5), (40, 0.15), (90, 0.08)]:
        g = graph_from_dense(jnp.asarray(_random_dense(rng, n, density, dtype, ties)))
        i, _, _ = _check(g)
        assert 0 < len(i) < int(np.isfinite(np.asarray(g.weights)).sum()) // 2


def test_steps_of_a_point_cloud_graph_are_every_edge_the_bounds_settle(rng):
    """Euclidean ε-graph: the edges settled without a search still equal the reference."""
    X = rng.standard_normal((150, 4))
    P = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    W = np.where(P < np.quantile(P, 0.1), P, np.inf)
    _check(graph_from_dense(jnp.asarray(W)))


@pytest.mark.parametrize("last", [0.9, 1.0])
def test_a_three_hop_path_beats_an_edge_no_two_hop_does(last):
    """0–1 (3.0) against 0–2–3–1 (1.0 + 1.0 + ``last``), with no two-hop path 0 → 1; the
    bounds do not settle 0–1 (1.0 out of 0, 0.9 or 1.0 into 1): the search decides. A
    shorter path removes the edge; an exact tie (3.0) keeps it."""
    W = np.full((5, 5), np.inf)
    for a, b, x in [(0, 1, 3.0), (0, 2, 1.0), (2, 3, 1.0), (3, 1, last), (1, 4, 5.0)]:
        W[a, b] = W[b, a] = x
    i, j, _ = _check(graph_from_dense(jnp.asarray(W)))
    pairs = set(zip(i.tolist(), j.tolist(), strict=True))
    assert ((0, 1) in pairs) == (last == 1.0)
    assert {(0, 2), (2, 3), (1, 3), (1, 4)} <= pairs


def test_steps_do_not_depend_on_the_order_of_a_rows_slots():
    """Rows given in any slot order (padding anywhere) give the same steps."""
    rng = np.random.default_rng(5)
    g = graph_from_dense(jnp.asarray(_random_dense(rng, 60, 0.12, np.float64)))
    idx, w = np.asarray(g.indices).copy(), np.asarray(g.weights).copy()
    perm = np.argsort(rng.random(idx.shape), axis=1)
    shuffled = NeighbourGraph(
        jnp.asarray(np.take_along_axis(idx, perm, 1)), jnp.asarray(np.take_along_axis(w, perm, 1))
    )
    for a, b in zip(shuffled.steps(), _check(g), strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_step_is_its_own_path_with_no_search(rng, monkeypatch):
    """`path(i, j, limit)` with ``limit`` the step's length returns the edge at once (no
    Dijkstra: ~10 ms each on 10⁶ frames), the same path as the unbounded search; with no
    limit, or an edge longer than it, the search runs."""
    import scipy.sparse.csgraph as csgraph

    g = graph_from_dense(_random_dense(rng, 60, 0.15, np.float64))
    i, j, w = g.steps()
    want = [g.path(int(a), int(b)).tolist() for a, b in zip(i, j, strict=True)]
    calls = []
    real = csgraph.dijkstra
    monkeypatch.setattr(csgraph, "dijkstra", lambda *a, **k: calls.append(1) or real(*a, **k))
    got = [g.path(int(a), int(b), float(x)).tolist() for a, b, x in zip(i, j, w, strict=True)]
    assert got == want and all(len(p) == 2 for p in got) and not calls
    g.path(int(i[0]), int(j[0]), float(w[0]) * 0.5)  # a limit below the edge: searched
    assert calls
