import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse.csgraph import shortest_path as sp_shortest
from sklearn.neighbors import kneighbors_graph

import fxspace as fx
from fxspace.errors import DisconnectedGraphError, FxspaceError


def _points(rng, n, dim=3):
    return rng.standard_normal((n, dim))


def _dense(X, q=None, factor=1.3):
    P = np.asarray(fx.pairwise_distances(jnp.asarray(X)))
    thr = float(fx.connecting_threshold(P)) * factor
    return P, np.asarray(fx.epsilon_graph(P, thr)), thr


def test_knn_graph_equals_sklearn(rng):
    X = _points(rng, 300, 5)
    ref = kneighbors_graph(X, 8, mode="distance")
    ref = ref.maximum(ref.T).toarray()
    for kw in ({"reduce_dim": None}, {"reduce_dim": None, "search": "tree"}):
        g = fx.neighbourhood_graph(X, k=8, **kw)
        np.testing.assert_allclose(fx.expression.to_scipy(g).toarray(), ref, rtol=1e-10)
        assert g.indices.shape[0] == 300 and g.indices.shape[1] >= 8


def test_reduced_search_refines_with_exact_distances(rng):
    # 3 informative axes + small noise in 40 more: the principal-axis search finds the
    # same neighbours, and the edge lengths are the exact full-space distances.
    Z = rng.standard_normal((400, 3)) * 10
    X = np.concatenate([Z, 0.01 * rng.standard_normal((400, 40))], axis=1)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=3)
    ref = kneighbors_graph(X, 6, mode="distance")
    np.testing.assert_allclose(
        fx.expression.to_scipy(g).toarray(), ref.maximum(ref.T).toarray(), rtol=1e-10
    )


def test_threshold_drops_long_edges(rng):
    X = _points(rng, 200)
    g = fx.neighbourhood_graph(X, k=12, threshold=0.5, reduce_dim=None)
    w = np.asarray(g.weights)
    assert np.all(w[np.isfinite(w)] <= 0.5)
    P = np.asarray(fx.pairwise_distances(jnp.asarray(X)))
    idx = np.asarray(g.indices)
    r, c = np.nonzero(np.isfinite(w))
    np.testing.assert_allclose(w[r, c], P[r, idx[r, c]], rtol=1e-10)


def test_graph_from_dense_round_trip(rng):
    _, W, _ = _dense(_points(rng, 120))
    g = fx.graph_from_dense(W)
    A = fx.expression.to_scipy(g).toarray()
    fin = np.isfinite(W) & ~np.eye(120, dtype=bool)
    np.testing.assert_array_equal(A != 0, fin)
    np.testing.assert_array_equal(A[fin], W[fin])
    assert g.indices.shape == (120, int(fin.sum(axis=1).max()))


@pytest.mark.parametrize("factor", [1.0, 1.3, 2.0])
def test_sparse_paths_equal_dense_floyd_paths(rng, factor):
    _, W, _ = _dense(_points(rng, 150), factor=factor)
    geo = fx.geodesic_distances(W)
    g = fx.graph_from_dense(W)
    D = np.asarray(geo.distances)
    for i, j in [(0, 149), (3, 77), (40, 41), (100, 5), (7, 7)]:
        p = fx.shortest_path(g, i, j)
        np.testing.assert_array_equal(p, fx.shortest_path(geo, i, j))
        assert np.isclose(sum(W[a, b] for a, b in zip(p[:-1], p[1:], strict=True)), D[i, j])


def test_sparse_components_and_disconnection(rng):
    X = np.concatenate([_points(rng, 50), _points(rng, 50) + 100.0])
    g = fx.neighbourhood_graph(X, k=5, reduce_dim=None)
    n_comp, labels = fx.expression.sparse_components(g)
    assert n_comp == 2 and len(set(labels[:50])) == 1 and labels[0] != labels[99]
    with pytest.raises(DisconnectedGraphError, match="2 connected components"):
        fx.expression.check_sparse_connected(g)
    with pytest.raises(DisconnectedGraphError, match="not reachable"):
        fx.shortest_path(g, 0, 99)
    ref = sp_shortest(fx.expression.to_scipy(g), directed=False, indices=[0])
    assert np.isinf(ref[0, 99])


def test_bad_arguments(rng):
    X = _points(rng, 20)
    with pytest.raises(FxspaceError, match="k must be"):
        fx.neighbourhood_graph(X, k=20)
    with pytest.raises(FxspaceError, match="NaN"):
        fx.neighbourhood_graph(np.where(np.eye(20, 3) > 0, np.nan, X), k=3)
    with pytest.raises(FxspaceError, match="search"):
        fx.neighbourhood_graph(X, k=3, search="ball")  # type: ignore[arg-type]


def test_knn_recall_against_sklearn():
    """Issue 45: the recall of the graph's neighbours against the exact k nearest
    (scikit-learn's brute force), 1.0 for the exact search, lower for a damaged graph."""
    from sklearn.neighbors import NearestNeighbors

    rng = np.random.default_rng(0)
    F = rng.normal(size=(1500, 40)).astype(np.float32)
    exact = fx.neighbourhood_graph(F, k=6, reduce_dim=None)
    assert fx.expression.knn_recall(F, exact, k=6, sample=300) == 1.0
    # the reduced search on isotropic noise misses many: the recall says how many
    approx = fx.neighbourhood_graph(F, k=6, reduce_dim=2, candidates=8)
    got = fx.expression.knn_recall(F, approx, k=6, sample=300, seed=1)
    rows = np.random.default_rng(1).choice(1500, 300, replace=False)
    nn = NearestNeighbors(n_neighbors=7).fit(F).kneighbors(F[rows])[1][:, 1:]
    have = np.asarray(approx.indices)[rows]
    want = float(np.mean([[a in set(h) for a in r] for r, h in zip(nn, have, strict=True)]))
    assert got == pytest.approx(want, abs=1e-9)
    assert got < 0.9
    # the distance ratio: the graph's k shortest edges against the exact k nearest
    q = fx.expression.knn_quality(F, approx, k=6, sample=300, seed=1)
    assert q.recall == got and q.sample == 300
    dist = NearestNeighbors(n_neighbors=7).fit(F).kneighbors(F[rows])[0][:, 1:]
    w = np.sort(np.asarray(approx.weights, np.float64)[rows], axis=1)[:, :6]
    assert q.distance_ratio == pytest.approx(np.mean(w.mean(1) / dist.mean(1)), rel=1e-5)
    assert q.distance_ratio > 1.0
    assert fx.expression.knn_quality(F, exact, k=6, sample=300) == (1.0, pytest.approx(1.0), 300)
    with pytest.raises(fx.FxspaceError, match="features"):
        fx.expression.knn_recall(F[:100], exact, k=6)


def test_dijkstra_csr_is_built_once_per_graph_and_never_served_to_another():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(200, 4))
    g = fx.neighbourhood_graph(X, k=5, reduce_dim=None)
    a, b = g.dijkstra_csr(), g.dijkstra_csr()
    assert a[0] is b[0]  # one build for the many searches of a route
    h = fx.expression.NeighbourGraph(g.indices, g.weights * 2.0)  # same indices, new weights
    np.testing.assert_allclose(h.dijkstra_csr()[0].toarray(), 2.0 * a[0].toarray())
    del h
    g2 = fx.neighbourhood_graph(X[::-1].copy(), k=5, reduce_dim=None)
    ref = fx.expression.to_scipy(g2).toarray()
    np.testing.assert_allclose(g2.dijkstra_csr()[0].toarray(), ref)
