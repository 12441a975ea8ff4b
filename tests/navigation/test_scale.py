import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation import sparse_hierarchy, sparse_links, sparse_route


def _ring(rng, n=400):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, 0.2 * np.pi / n, n)
    X = np.stack([np.cos(t), np.sin(t)], 1) * 10 + 0.05 * rng.standard_normal((n, 2))
    return X


def test_route_is_a_shortest_walk_through_the_keys(rng):
    X = _ring(rng)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    keys = [0, 100, 250, 399]
    r = sparse_route(g, keys)
    assert r[0] == 0 and r[-1] == 399
    assert all(k in r.tolist() for k in keys)
    A = fx.expression.to_scipy(g).toarray()
    assert all(A[a, b] > 0 for a, b in zip(r[:-1], r[1:], strict=True))  # graph walk
    from scipy.sparse.csgraph import dijkstra

    D = dijkstra(A, directed=False)
    length = sum(A[a, b] for a, b in zip(r[:-1], r[1:], strict=True))
    assert np.isclose(length, sum(D[a, b] for a, b in zip(keys[:-1], keys[1:], strict=True)))


def test_links_follow_the_ring_and_never_cross_it(rng):
    X = _ring(rng)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    cf = np.array(
        [
            np.argmin(np.abs(np.angle(np.exp(1j * (np.arctan2(X[:, 1], X[:, 0]) - a)))))
            for a in angles
        ]
    )
    links, bridges = sparse_links(g, X, cf, near=4)
    # each centre is linked to its two ring neighbours only: the path to any other centre
    # passes next to a centre in between
    assert links.sum(axis=1).tolist() == [2] * 8 and not bridges.any()
    for i in range(8):
        assert links[i, (i + 1) % 8] and links[i, (i - 1) % 8]


def test_hierarchy_levels_and_links(rng):
    X = _ring(rng, 600)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    h = sparse_hierarchy(X, g, levels=3, c0=4, key=jax.random.key(0))
    assert [lv.n_clusters for lv in h] == [4, 8, 16]
    for lv in h:
        assert lv.fcm.memberships.shape == (600, min(8, lv.n_clusters))
        n_comp = __import__("scipy.sparse.csgraph", fromlist=["x"]).connected_components(
            lv.links, directed=False
        )[0]
        assert n_comp == 1  # every centre reachable (links + bridges)
        assert np.all(np.asarray(lv.center_frames) < 600)


def test_route_needs_keys():
    g = fx.graph_from_dense(np.array([[0.0, 1.0], [1.0, 0.0]]))
    with pytest.raises(fx.FxspaceError, match="key_frames"):
        sparse_route(g, [])
