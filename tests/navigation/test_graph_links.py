"""Links on a NeighbourGraph (issue 45): the same rule and code as on Geodesics, checked
pair by pair; the level where every frame is a centre; bridges only on request."""

import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation import (
    LinkRule,
    build_hierarchy,
    center_links,
    finest_level,
    frame_links,
    frame_path,
)


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
    rho = fx.default_link_radius(X[cf], 0.5)
    links, bridges = center_links(X, g, cf, rho)
    # each centre is linked to its two ring neighbours only: the path to any other centre
    # passes next to a centre in between
    assert links.sum(axis=1).tolist() == [2] * 8 and bridges.nnz == 0
    for i in range(8):
        assert links[i, (i + 1) % 8] and links[i, (i - 1) % 8]


def test_hierarchy_levels_and_links(rng):
    X = _ring(rng, 600)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    h = build_hierarchy(X, g, levels=3, c0=4, key=jax.random.key(0), finest=False,
                        fcm=fx.navigation.TruncatedFuzzyCMeans(nearest=8)).levels
    assert [lv.n_clusters for lv in h] == [4, 8, 16]
    for lv in h:
        assert lv.fit.memberships.shape == (600, min(8, lv.n_clusters)) and lv.converged
        # ρ by the experiment keeps every swept level in one piece, without bridges
        assert fx.navigation.link_graph_connected(lv) and lv.n_bridges == 0
        assert np.all(np.asarray(lv.center_frames) < 600)


def test_route_needs_keys():
    g = fx.graph_from_dense(np.array([[0.0, 1.0], [1.0, 0.0]]))
    with pytest.raises(fx.FxspaceError, match="key_frames"):
        frame_path(g, [])


def _rule_reference(paths, Y, cf, rho):
    """The paper's rule pair by pair (the paths' own shortest path, every other centre)."""
    c, pos = len(cf), Y[cf]
    out = np.zeros((c, c), bool)
    for i in range(c):
        for j in range(i + 1, c):
            try:
                path = paths.path(int(cf[i]), int(cf[j]))
            except fx.errors.DisconnectedGraphError:
                continue
            keep = (np.arange(c) != i) & (np.arange(c) != j) & (cf != cf[i]) & (cf != cf[j])
            a, b = Y[path[:-1]], Y[path[1:]]
            ab = b - a
            L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
            q = pos[keep]
            t = np.clip(np.einsum("skd,sd->sk", q[None] - a[:, None], ab) / L2[:, None], 0, 1)
            d = np.linalg.norm(q[None] - (a[:, None] + t[..., None] * ab[:, None]), axis=-1)
            out[i, j] = out[j, i] = cf[i] != cf[j] and not np.any(d < rho)
    return out


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


@pytest.mark.parametrize("seed, k, split", [(0, 5, False), (2, 4, True)])
def test_links_equal_the_rule_pair_by_pair(seed, k, split):
    """On a k-NN graph whose paths bend in 2-D (the features are 3-D), the links are the
    rule walked pair by pair, exact up to EXACT_CENTRES; bridges only on request, and
    then they join every piece the frame graph joins (a spanning forest)."""
    rng, Y, g = _random_case(seed, k=k, split=split)
    for nc in (30, 90):
        cf = rng.choice(len(Y), nc, replace=False)
        rho = fx.default_link_radius(Y[cf], 0.3)
        L, B = center_links(Y, g, cf, rho)
        assert _is_sym_bool_csr(L, nc) and _is_sym_bool_csr(B, nc) and B.nnz == 0
        np.testing.assert_array_equal(L.toarray(), _rule_reference(g, Y, cf, rho))
        L2, B2 = center_links(Y, g, cf, rho, bridge=True)
        assert not (B2 > L2).nnz and ((L2 != B2) != L).nnz == 0  # bridges ⊂ links
        from scipy.sparse.csgraph import connected_components

        parts = connected_components(fx.expression.to_scipy(g), directed=False)[1][cf]
        assert connected_components(L2, directed=False)[0] == len(np.unique(parts))


@pytest.mark.parametrize("seed, k, split", [(4, 5, False), (5, 3, True)])
def test_frame_links_equal_the_rule_with_every_frame_a_centre(seed, k, split):
    _, Y, g = _random_case(seed, n=80, k=k, split=split)
    T = len(Y)
    rho = fx.default_link_radius(Y, 0.5)
    L, B = frame_links(g, Y, rho=rho)
    assert _is_sym_bool_csr(L, T) and _is_sym_bool_csr(B, T) and B.nnz == 0
    np.testing.assert_array_equal(L.toarray(), _rule_reference(g, Y, np.arange(T), rho))
    L2, _ = center_links(Y, g, np.arange(T), rho)
    assert (L2 != L).nnz == 0
    # every link is a graph edge that is itself a shortest path
    from scipy.sparse.csgraph import dijkstra

    A = fx.expression.to_scipy(g).toarray()
    D = dijkstra(fx.expression.to_scipy(g), directed=False)
    i, j = L.nonzero()
    assert np.all(A[i, j] > 0) and np.allclose(A[i, j], D[i, j])


def test_finest_level_appended(rng):
    X = _ring(rng, 300)
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    h = build_hierarchy(X, g, levels=2, c0=4, key=jax.random.key(0), nearest=8)
    assert h.sizes == (4, 8, 300)
    top = h.levels[-1]
    assert top.init == "frames" and top.converged
    assert np.array_equal(top.center_frames, np.arange(300))
    assert np.allclose(top.centers, X) and top.radius > 0
    L, B = frame_links(g, X, rho=top.radius)
    assert (top.links != L).nnz == 0 and (top.bridges != B).nnz == 0 and B.nnz == 0
    assert np.array_equal(top.lengths.indptr, top.links.indptr)
    assert finest_level(X, g, links=False).links.nnz == 0
    assert len(build_hierarchy(X, g, levels=2, c0=4, finest=False).levels) == 2
    wide = build_hierarchy(X, g, levels=2, c0=4, links=LinkRule(rho=3.0, bridges=True))
    assert all(fx.navigation.link_graph_connected(lv) for lv in wide.levels)


def test_link_inputs_are_checked(rng):
    X = _ring(rng, 50)
    g = fx.neighbourhood_graph(X, k=4, reduce_dim=None)
    with pytest.raises(fx.FxspaceError, match="embedding"):
        center_links(X[:10], g, np.arange(5), 0.1)
    with pytest.raises(fx.FxspaceError, match="center_frames"):
        center_links(X, g, np.array([0, 99]), 0.1)
    with pytest.raises(fx.FxspaceError, match="near"):
        LinkRule(near=0)
    with pytest.raises(fx.FxspaceError, match="rho"):
        frame_links(g, X, rho=0.0)
