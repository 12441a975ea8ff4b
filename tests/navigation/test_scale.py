import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation import (
    build_hierarchy,
    center_links,
    finest_level,
    frame_links,
    frame_path,
)

# the sparse implementation itself, for its `near` / `batch` options
from fxspace.navigation._scale import sparse_links as _sparse_links


def _ring(rng, n=400):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, 0.2 * np.pi / n, n)
    X = np.stack([np.cos(t), np.sin(t)], 1) * 10 + 0.05 * rng.standard_normal((n, 2))
    return X


def test_route_is_a_shortest_walk_through_the_keys(rng):
    X = _ring(rng)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    keys = [0, 100, 250, 399]
    r = frame_path(g, keys)
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
    links, bridges = _sparse_links(g, X, cf, near=4)
    L2, B2 = center_links(X, g, cf)  # the public front, default near
    assert (L2 != links).nnz == 0 and (B2 != bridges).nnz == 0
    # each centre is linked to its two ring neighbours only: the path to any other centre
    # passes next to a centre in between
    assert links.sum(axis=1).tolist() == [2] * 8 and bridges.nnz == 0
    for i in range(8):
        assert links[i, (i + 1) % 8] and links[i, (i - 1) % 8]


def test_hierarchy_levels_and_links(rng):
    X = _ring(rng, 600)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    h = build_hierarchy(X, g, levels=3, c0=4, key=jax.random.key(0)).levels
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
        frame_path(g, [])


# -- issue 24: sparse links against the dense (c, c) implementation they replace ---------


def _dense_reference_links(graph, embedding, center_frames, rho=None, near=6, batch=64):
    """The implementation before issue 24 (a dense ``(c, c)`` Dcc and full Dijkstra rows),
    kept verbatim as the reference."""
    from scipy.sparse.csgraph import connected_components, dijkstra
    from scipy.spatial import cKDTree

    Y = np.asarray(embedding, np.float64)
    cf = np.asarray(center_frames, np.int64)
    c = len(cf)
    links = np.zeros((c, c), bool)
    bridges = np.zeros((c, c), bool)
    if c < 2:
        return links, bridges
    pos = Y[cf]
    tree = cKDTree(pos)
    if rho is None:
        nn = tree.query(pos, k=2)[0][:, 1]
        rho = 0.5 * float(np.median(nn[nn > 0])) if np.any(nn > 0) else 0.0
    kq = min(near + 1, c)
    cand = tree.query(pos, k=kq)[1][:, 1:]
    csr = fx.expression.to_scipy(graph)
    Dcc = np.full((c, c), np.inf)
    for s in range(0, c, batch):
        rows = np.arange(s, min(s + batch, c))
        d, pred = dijkstra(csr, directed=False, indices=cf[rows], return_predecessors=True)
        Dcc[rows] = d[:, cf]
        for r, i in enumerate(rows):
            for j in cand[i]:
                if links[i, j] or not np.isfinite(d[r, cf[j]]):
                    continue
                path = [cf[j]]
                while path[-1] != cf[i]:
                    path.append(pred[r, path[-1]])
                dist, idx = tree.query(Y[path], k=min(3, c), distance_upper_bound=rho)
                other = np.isfinite(dist) & (idx != i) & (idx != j) & (idx < c)
                other &= cf[np.minimum(idx, c - 1)] != cf[i]
                other &= cf[np.minimum(idx, c - 1)] != cf[j]
                if not other.any():
                    links[i, j] = links[j, i] = True
    np.fill_diagonal(Dcc, np.inf)
    while True:
        n_comp, lab = connected_components(links, directed=False)
        if n_comp == 1:
            break
        sizes = np.bincount(lab)
        inside = lab == int(np.argmin(sizes))
        sub = Dcc[np.ix_(inside, ~inside)]
        if not np.isfinite(sub).any():
            break  # the frame graph itself is disconnected
        a, b = np.unravel_index(np.argmin(sub), sub.shape)
        i, j = np.flatnonzero(inside)[a], np.flatnonzero(~inside)[b]
        links[i, j] = links[j, i] = bridges[i, j] = bridges[j, i] = True
    return links, bridges


def _random_case(seed, n=240, k=5, split=False):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 3))
    if split:  # two far blobs: the frame graph itself has two parts
        X[: n // 2, 0] += 50.0
    g = fx.neighbourhood_graph(X, k=k, reduce_dim=None)
    return rng, X[:, :2], g


def _is_sym_bool_csr(m, c):
    from scipy.sparse import csr_array

    return (
        isinstance(m, csr_array)
        and m.shape == (c, c)
        and m.dtype == bool
        and (m != m.T).nnz == 0
        and not m.diagonal().any()
    )


@pytest.mark.parametrize(
    "seed, near, batch, k, split",
    [(0, 6, 64, 5, False), (1, 2, 7, 3, False), (2, 4, 16, 4, True), (3, 6, 5, 3, True)],
)
def test_sparse_links_equal_the_dense_reference(seed, near, batch, k, split):
    rng, Y, g = _random_case(seed, k=k, split=split)
    for nc in (30, 90):
        cf = rng.choice(len(Y), nc, replace=False)
        L0, B0 = _dense_reference_links(g, Y, cf, near=near, batch=batch)
        L1, B1 = _sparse_links(g, Y, cf, near=near, batch=batch)
        assert _is_sym_bool_csr(L1, nc) and _is_sym_bool_csr(B1, nc)
        assert np.array_equal(L1.toarray(), L0) and np.array_equal(B1.toarray(), B0)
        assert B0.any()  # the case exercises the bridging
        assert not (B1 > L1).nnz  # bridges ⊂ links


@pytest.mark.parametrize("seed, near, k, split", [(4, 6, 5, False), (5, 3, 3, True)])
def test_frame_links_equal_the_general_rule_with_every_frame_a_centre(seed, near, k, split):
    _, Y, g = _random_case(seed, n=200, k=k, split=split)
    T = len(Y)
    L0, B0 = _dense_reference_links(g, Y, np.arange(T), near=near)
    L1, B1 = _sparse_links(g, Y, np.arange(T), near=near)
    L2, B2 = frame_links(g, Y, near=near)
    assert _is_sym_bool_csr(L2, T) and _is_sym_bool_csr(B2, T)
    for L, B in ((L1, B1), (L2, B2)):
        assert np.array_equal(L.toarray(), L0) and np.array_equal(B.toarray(), B0)
    # every link is a graph edge that is itself a shortest path
    from scipy.sparse.csgraph import dijkstra

    A = fx.expression.to_scipy(g).toarray()
    D = dijkstra(fx.expression.to_scipy(g), directed=False)
    i, j = L2.nonzero()
    assert np.all(A[i, j] > 0) and np.allclose(A[i, j], D[i, j])


def test_finest_level_appended(rng):
    X = _ring(rng, 300)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    h = build_hierarchy(X, g, levels=2, c0=4, key=jax.random.key(0), finest=True).levels
    assert [lv.n_clusters for lv in h] == [4, 8, 300]
    top = h[-1]
    assert top.fcm is None and np.array_equal(top.center_frames, np.arange(300))
    assert np.allclose(top.centers, X) and top.radius > 0
    L, B = frame_links(g, X)
    assert (top.links != L).nnz == 0 and (top.bridges != B).nnz == 0
    assert np.array_equal(top.lengths.indptr, top.links.indptr)
    from scipy.sparse.csgraph import connected_components

    assert connected_components(top.links, directed=False)[0] == 1
    assert finest_level(X, g, links=False).links.nnz == 0
    assert len(build_hierarchy(X, g, levels=2, c0=4, key=jax.random.key(0)).levels) == 2


def test_link_inputs_are_checked(rng):
    X = _ring(rng, 50)
    g = fx.neighbourhood_graph(X, k=4, reduce_dim=None)
    with pytest.raises(fx.FxspaceError, match="embedding"):
        center_links(X[:10], g, np.arange(5))
    with pytest.raises(fx.FxspaceError, match="center_frames"):
        center_links(X, g, np.array([0, 99]))
    with pytest.raises(fx.FxspaceError, match="near"):
        frame_links(g, X, near=0)
    with pytest.raises(fx.FxspaceError, match="rho"):
        frame_links(g, X, rho=0.0)
