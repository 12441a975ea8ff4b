"""Navigation on a NeighbourGraph (issues 24, 45): the same routes as on Geodesics,
refined level by level to frames."""

import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation import (
    Hierarchy,
    NavigationError,
    Route,
    bridge_keys,
    build_hierarchy,
    is_graph_walk,
    make_route,
    navigate,
    path_candidates,
    refine_route,
)


@pytest.fixture(scope="module")
def space():
    rng = np.random.default_rng(0)
    n = 600
    t = rng.uniform(0, 3 * np.pi, n)
    X = np.stack([t * np.cos(t), t * np.sin(t), rng.normal(0, 1.0, n)], 1)
    g = fx.neighbourhood_graph(X, k=8, reduce_dim=None)
    assert fx.expression.sparse_components(g)[0] == 1
    Y = X[:, :2]
    h = build_hierarchy(Y, g, levels=3, c0=4, key=jax.random.key(0), nearest=8)
    W = fx.expression.to_scipy(g).toarray()
    W[W == 0] = np.inf
    return Y, g, h, W


def _linked(lv, cs):
    return all(bool(lv.links[a, b]) for a, b in zip(cs[:-1], cs[1:], strict=True))


def test_navigate_links_every_level_and_walks_the_graph(space):
    Y, g, h, W = space
    keys, _ = bridge_keys(h, g, 0, [0, 2, 3, 1])
    routes = navigate(h, g, keys)
    assert [r.level for r in routes] == list(range(len(h.levels)))
    for r in routes:
        lv = h.levels[r.level]
        assert _linked(lv, r.centres)
        if r.level > 0:  # refinement cuts loops: no centre repeats
            assert len(set(r.centres)) == len(r.centres)
        assert np.array_equal(r.key_frames, lv.center_frames[list(r.centres)])
        assert is_graph_walk(r.frames, W)
        assert r.frames[0] == r.key_frames[0] and r.frames[-1] == r.key_frames[-1]
    fine = routes[-1]
    # at the finest level every frame is a centre: the key frames are the frames
    assert np.array_equal(fine.frames, fine.key_frames)
    # the route spans the animator's first to last frame down to the frames
    one_way = navigate(h, g, bridge_keys(h, g, 0, [0, 3])[0])
    anchors = one_way[0].anchors
    piece = fx.navigation.link_components(h.levels[-1])  # the finest: centre = frame
    if piece[anchors[0]] == piece[anchors[-1]]:
        assert one_way[-1].frames[0] == anchors[0] and one_way[-1].frames[-1] == anchors[-1]
    else:  # the rule left them in two pieces: the route keeps to one of them
        assert len(set(piece[list(one_way[-1].centres)].tolist())) == 1


def test_frame_path_is_the_shortest_walk_through_the_keys(space):
    Y, g, h, W = space
    from scipy.sparse.csgraph import dijkstra

    lv = h.levels[1]
    a = 0
    b = int(lv.neighbours(a)[0])
    r = make_route(h, g, 1, [a, b])
    D = dijkstra(fx.expression.to_scipy(g), directed=False)
    length = sum(W[u, v] for u, v in zip(r.frames[:-1], r.frames[1:], strict=True))
    assert np.isclose(length, D[lv.center_frames[a], lv.center_frames[b]])
    assert np.isclose(lv.lengths[a, b], D[lv.center_frames[a], lv.center_frames[b]])


def test_unlinked_picks_are_refused_and_bridged(space):
    Y, g, h, _ = space
    lv = h.levels[-1]
    piece = fx.navigation.link_components(lv)
    a = int(np.argmax(np.bincount(piece)[piece]))  # a centre of the largest piece
    nb = set(lv.neighbours(a).tolist())
    b = next(k for k in range(lv.n_clusters) if k != a and k not in nb and piece[k] == piece[a])
    with pytest.raises(NavigationError, match="not linked"):
        make_route(h, g, len(h.levels) - 1, [a, b])
    keys, notes = bridge_keys(h, g, len(h.levels) - 1, [a, a, b])
    assert keys[0] == a and keys[-1] == b and _linked(lv, keys)
    assert any("dropped" in n for n in notes) and any("bridged" in n for n in notes)


def test_refine_with_picks_and_candidates(space):
    Y, g, h, _ = space
    r0 = make_route(h, g, 0, [0, int(h.levels[0].neighbours(0)[0])])
    cands = path_candidates(h, 1, r0.frames)
    assert len(cands) and np.all(cands < h.levels[1].n_clusters)
    cpos = Y[h.levels[1].center_frames[cands]]
    d = np.min(np.linalg.norm(cpos[:, None] - Y[r0.frames][None], axis=-1), 1)
    assert np.all(d <= h.levels[1].radius + 1e-12)
    auto = refine_route(h, g, r0)
    assert isinstance(auto, Route) and auto.level == 1 and _linked(h.levels[1], auto.centres)
    picked = refine_route(h, g, r0, picks=auto.centres[:2])
    assert picked.centres == auto.centres[:2]
    fine = navigate(h, g, r0.centres, to_level=len(h.levels) - 1)[-1]
    with pytest.raises(NavigationError, match="finest"):
        refine_route(h, g, fine)


def test_bad_requests_name_the_argument(space):
    Y, g, h, _ = space
    with pytest.raises(NavigationError, match="level"):
        make_route(h, g, 9, [0])
    with pytest.raises(NavigationError, match="centre 99"):
        make_route(h, g, 0, [99])
    with pytest.raises(NavigationError, match="centres is empty"):
        make_route(h, g, 0, [])
    with pytest.raises(fx.FxspaceError, match="Hierarchy"):
        make_route([], g, 0, [0])
    with pytest.raises(NavigationError, match="paths"):
        make_route(h, np.eye(3), 0, [0, 1])
    with pytest.raises(NavigationError, match="embedding"):
        refine_route(Hierarchy(h.levels, Y[:5]), g, make_route(h, g, 0, [0]))
    with pytest.raises(NavigationError, match="to_level"):
        navigate(h, g, [0], to_level=7)
    with pytest.raises(fx.FxspaceError, match="frames"):
        path_candidates(h, 0, [])


@pytest.mark.slow
def test_finest_level_and_route_at_20000_frames():
    from scipy.sparse.csgraph import connected_components

    from fxspace.navigation import finest_level

    rng = np.random.default_rng(1)
    n = 20000
    t = rng.uniform(0, 3 * np.pi, n)
    X = np.stack([t * np.cos(t), t * np.sin(t), rng.normal(0, 1.0, n)], 1)
    X = X.astype(np.float32)  # the tests run with x64 on: float64 would be ~10× slower here
    g = fx.neighbourhood_graph(X, k=8, reduce_dim=None)
    Y = X[:, :2]
    h = build_hierarchy(Y, g, levels=3, c0=10, key=jax.random.key(0), nearest=8)
    top = h.levels[-1]
    assert top.n_clusters == n and top.links.nnz < 20 * n  # O(T·K)
    assert h.converged and all(lv.n_bridges == 0 for lv in h.levels)
    del connected_components, finest_level
    keys, _ = bridge_keys(h, g, 0, [0, 4, 9])
    routes = navigate(h, g, keys)
    csr = fx.expression.to_scipy(g)
    for r in routes:
        assert _linked(h.levels[r.level], r.centres)
        f = r.frames
        assert np.all(f[1:] != f[:-1]) and np.all(csr[f[:-1], f[1:]] > 0)


def test_levels_round_trip_through_arrays(space, tmp_path):
    """`hierarchy_to_arrays` → ``.npz`` → `hierarchy_from_arrays`: the same centres,
    links, bridges and lengths, and the same routes navigated on the levels read back."""
    from fxspace.navigation import hierarchy_from_arrays, hierarchy_to_arrays

    Y, g, h, _ = space
    np.savez(tmp_path / "h.npz", **hierarchy_to_arrays(h))
    with np.load(tmp_path / "h.npz") as z:
        back = hierarchy_from_arrays(z)
    assert len(back.levels) == len(h.levels)
    for a, b in zip(h.levels, back.levels, strict=True):
        assert a.n_clusters == b.n_clusters and b.result == a.result
        np.testing.assert_array_equal(a.fit.indices, b.fit.indices)
        np.testing.assert_array_equal(a.center_frames, b.center_frames)
        np.testing.assert_array_equal(a.centers, b.centers)
        for m in ("links", "bridges"):
            assert (getattr(a, m) != getattr(b, m)).nnz == 0
        np.testing.assert_array_equal(a.lengths.toarray(), b.lengths.toarray())
        assert a.radius == b.radius
    keys, _ = bridge_keys(h, g, 0, [0, h.levels[0].n_clusters - 1])
    r1 = navigate(h, g, keys)
    r2 = navigate(back, g, keys)
    np.testing.assert_array_equal(r1[-1].frames, r2[-1].frames)
    with pytest.raises(fx.errors.FxspaceError, match="n_levels"):
        hierarchy_from_arrays({"x": np.zeros(1)})


def test_link_pairs_dense_and_sparse_agree(space):
    """`link_pairs` lists each link once (i < j), from a sparse level's csr_array and from
    the same links as a dense matrix."""
    from fxspace.navigation import link_pairs

    _, _, h, _ = space
    for lv in h.levels:
        i, j = link_pairs(lv.links)
        di, dj = link_pairs(lv.links.toarray())
        np.testing.assert_array_equal(
            np.sort(i * lv.n_clusters + j), np.sort(di * lv.n_clusters + dj)
        )
        assert np.all(i < j) and len(i) == lv.links.nnz // 2
    e = link_pairs(np.zeros((3, 3), bool))
    assert len(e[0]) == len(e[1]) == 0
    with pytest.raises(fx.FxspaceError, match="no links"):
        link_pairs(None)  # a level without links says so (never an empty answer)


@pytest.mark.parametrize("small", [4096, 0])
def test_bounded_chain_search_is_the_unbounded_one(space, small, monkeypatch):
    """The chain of links between two centres — in Python, stopped at the target, or
    (``small = 0``) scipy's within growing bounds — is the chain of scipy's unbounded
    Dijkstra over the level's links (near and far pairs; a pair in another piece is
    refused as before)."""
    from scipy.sparse.csgraph import dijkstra

    import fxspace.navigation._routes as routes
    from fxspace.navigation._routes import _link_path

    monkeypatch.setattr(routes, "_SMALL_SEARCH", small)
    _, _, h, _ = space
    lv = h.levels[-1]  # every frame a centre
    piece = fx.navigation.link_components(lv)
    w = lv.lengths.astype(np.float64).tocsr()
    w.data = np.where(np.isfinite(w.data), w.data, 0.0) + 1e-12
    rng = np.random.default_rng(1)
    checked = 0
    linked = np.flatnonzero(np.diff(lv.links.tocsr().indptr) > 0)
    for a in rng.choice(linked, 12, replace=False):
        d, pred = dijkstra(w, directed=False, indices=a, return_predecessors=True)
        same = np.flatnonzero(piece == piece[a])
        other = np.flatnonzero(piece != piece[a])
        for b in [int(lv.neighbours(a)[0]), *rng.choice(same, 4).tolist(),
                  *rng.choice(other, 1).tolist()]:  # fmt: skip
            if b == a:
                continue
            if piece[b] != piece[a]:
                with pytest.raises(NavigationError, match="cannot be reached"):
                    _link_path(lv, int(a), b)
                continue
            chain = [b]
            while chain[-1] != a:
                chain.append(int(pred[chain[-1]]))
            assert _link_path(lv, int(a), b) == chain[::-1]
            checked += 1
    assert checked >= 40
