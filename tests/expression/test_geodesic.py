import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components as sp_cc
from scipy.sparse.csgraph import csgraph_from_dense, minimum_spanning_tree
from scipy.sparse.csgraph import shortest_path as sp_shortest

import fxspace as fx


def _graph(rng, n, q, dim=3):
    X = rng.standard_normal((n, dim))
    P = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    thr = np.quantile(P[np.triu_indices(n, 1)], q)
    return P, np.asarray(fx.epsilon_graph(P, thr)), thr


def _scipy(W):
    return sp_shortest(np.where(np.isinf(W), 0, W), method="D", directed=False)


def test_epsilon_graph_definition(rng):
    P, W, thr = _graph(rng, 20, 0.3)
    assert np.all(np.diag(W) == 0)
    off = ~np.eye(20, dtype=bool)
    np.testing.assert_array_equal(np.isfinite(W[off]), P[off] <= thr)
    np.testing.assert_array_equal(W[np.isfinite(W)], P[np.isfinite(W)])


@pytest.mark.parametrize("method", ["scan", "blocked"])
@pytest.mark.parametrize("q", [0.03, 0.1, 0.5])
def test_floyd_matches_scipy(rng, method, q):
    P, W, _ = _graph(rng, 150, q)
    D = np.asarray(fx.floyd_warshall(W, method=method, block=32))
    ref = _scipy(W)
    np.testing.assert_array_equal(np.isinf(D), np.isinf(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(D[fin], ref[fin], rtol=1e-12)


def test_blocked_with_padding_and_float32(rng):
    P, W, _ = _graph(rng, 301, 0.05)
    D = np.asarray(fx.floyd_warshall(jnp.asarray(W, jnp.float32), method="blocked", block=64))
    ref = _scipy(W)
    fin = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(D), fin)
    np.testing.assert_allclose(D[fin], ref[fin], rtol=1e-5)


@pytest.mark.parametrize("cols", [40, 1040, 4216])
def test_tiled_minplus_update_equals_numpy(rng, cols):
    """The phase-3 update (whole row blocks, or column tiles once a row block passes
    1 MiB) is the plain ``min(D, C ⊗ R)``; `_col_pad` always gives a column count the
    update can tile."""
    from fxspace.expression._floyd_kernels import _col_pad, _col_tiles, _minplus_update

    D = rng.uniform(0, 4, (128, cols)).astype(np.float32)
    C = rng.uniform(0, 2, (128, 8)).astype(np.float32)
    R = rng.uniform(0, 2, (8, cols)).astype(np.float32)
    D[3, 5] = np.inf
    ref = np.minimum(D, np.min(C[:, :, None] + R[None, :, :], axis=1))
    out = np.asarray(_minplus_update(jnp.asarray(D), jnp.asarray(C), jnp.asarray(R), 64))
    np.testing.assert_array_equal(out, ref)
    assert _col_tiles(2464, 56, 4) == 1 and _col_tiles(4800, 64, 4) > 1
    for m in (40, 64, 2464, 4216, 4800, 9000):
        mc, nc = _col_pad(m, 64, 4), _col_tiles(m, 64, 4)
        assert m <= mc < m + 8 * nc and mc % nc == 0 and (mc // nc) % 8 == 0


def test_directed_graph(rng):
    n = 40
    W = np.where(rng.random((n, n)) < 0.1, rng.random((n, n)) + 0.1, np.inf)
    np.fill_diagonal(W, 0)
    ref = sp_shortest(np.where(np.isinf(W), 0, W), directed=True)
    np.testing.assert_allclose(fx.floyd_warshall(W), ref, rtol=1e-12)


def test_paths_sum_to_geodesic(rng):
    P, W, _ = _graph(rng, 120, 0.05)
    geo = fx.geodesic_distances(W)
    D = np.asarray(geo.distances)
    for i, j in rng.integers(0, 120, (25, 2)):
        if not np.isfinite(D[i, j]):
            with pytest.raises(fx.DisconnectedGraphError):
                fx.shortest_path(geo, i, j)
            continue
        path = fx.shortest_path(geo, i, j)
        assert path[0] == i and path[-1] == j
        length = sum(W[a, b] for a, b in zip(path[:-1], path[1:], strict=True))
        np.testing.assert_allclose(length, D[i, j], rtol=1e-10)


def test_next_hop_dense_equals_neighbour_search(rng):
    P, W, _ = _graph(rng, 90, 0.1)
    geo = fx.geodesic_distances(W)
    dense = fx.next_hops(W, geo.distances)
    sparse = fx.next_hops(W, geo.distances, max_degree=64)
    D = np.asarray(geo.distances)
    # both give valid first steps: W[i,k] + D[k,j] == D[i,j]
    for nxt in (np.asarray(dense), np.asarray(sparse)):
        i, j = np.nonzero(np.isfinite(D) & ~np.eye(90, dtype=bool))
        k = nxt[i, j]
        np.testing.assert_allclose(W[i, k] + D[k, j], D[i, j], rtol=1e-10)
    assert np.all(np.asarray(dense)[~np.isfinite(D)] == -1)


def test_jit_vmap(rng):
    P, W, _ = _graph(rng, 60, 0.1)
    geo = jax.jit(fx.geodesic_distances)(W)
    np.testing.assert_allclose(geo.distances, fx.geodesic_distances(W).distances)
    thr = jnp.asarray([0.5, 1.0, 2.0])
    Ws = jax.vmap(lambda t: fx.epsilon_graph(P, t))(thr)
    Ds = jax.vmap(fx.floyd_warshall)(Ws)
    for k in range(3):
        np.testing.assert_allclose(Ds[k], _scipy(np.asarray(Ws[k])), rtol=1e-12)


def test_grad_is_path_indicator(rng):
    P, W, _ = _graph(rng, 30, 0.3)
    geo = fx.geodesic_distances(W)
    i, j = 0, int(np.argmax(np.where(np.isfinite(geo.distances[0]), geo.distances[0], -1)))
    g = jax.grad(lambda w: fx.floyd_warshall(w)[i, j])(jnp.asarray(W))
    path = fx.shortest_path(geo, i, j)
    expect = np.zeros_like(W)
    for a, b in zip(path[:-1], path[1:], strict=True):
        expect[a, b] += 1
    off = ~np.eye(len(W), dtype=bool)  # the diagonal is the constant 0 of epsilon_graph
    gs = np.asarray(g) + np.asarray(g).T
    np.testing.assert_allclose(gs[off], (expect + expect.T)[off], atol=1e-12)


def test_components_and_connecting_threshold(rng):
    P, W, _ = _graph(rng, 80, 0.02)
    n, lab = fx.connected_components(W)
    n_ref, _ = sp_cc(np.isfinite(W) & ~np.eye(80, dtype=bool), directed=False)
    assert int(n) == n_ref
    thr = float(fx.connecting_threshold(P))
    np.testing.assert_allclose(thr, minimum_spanning_tree(P).max(), rtol=1e-12)
    assert int(fx.connected_components(fx.epsilon_graph(P, thr))[0]) == 1
    assert int(fx.connected_components(fx.epsilon_graph(P, thr * 0.999))[0]) > 1
    with pytest.raises(fx.DisconnectedGraphError, match="smallest threshold that connects"):
        fx.check_connected(fx.epsilon_graph(P, thr * 0.999), P)


def test_bad_input():
    with pytest.raises(ValueError, match="square"):
        fx.geodesic_distances(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="method"):
        fx.floyd_warshall(np.zeros((3, 3)), method="dijkstra")
    geo = fx.geodesic_distances(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="out of range"):
        fx.shortest_path(geo, 0, 7)


@pytest.mark.data
def test_real_capture_graph_matches_scipy(data_dir):
    """AnimFace jaw take, every 8th frame: connected and disconnected ε-graphs vs scipy."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_jaw.c3d")
    pos, _ = fx.clean_frames(seq.positions[::8])
    P = np.asarray(fx.pairwise_distances(fx.distance_features(pos)))
    t0 = float(fx.connecting_threshold(P))
    for eps in (0.7 * t0, 1.2 * t0):
        W = np.asarray(fx.epsilon_graph(P, eps))
        geo = fx.geodesic_distances(W)
        ref = _scipy(W)
        D = np.asarray(geo.distances)
        np.testing.assert_array_equal(np.isfinite(D), np.isfinite(ref))
        fin = np.isfinite(ref)
        np.testing.assert_allclose(D[fin], ref[fin], rtol=1e-10)
        n_ref, _ = sp_cc(np.isfinite(W) & ~np.eye(len(W), dtype=bool), directed=False)
        assert int(fx.connected_components(W)[0]) == n_ref
    assert n_ref == 1  # the last (1.2 × connecting) graph is connected


@pytest.mark.parametrize("method", ["scan", "blocked"])
def test_next_hop_from_recurrence_is_valid(rng, method):
    P, W, _ = _graph(rng, 130, 0.04)
    geo = fx.geodesic_distances(W, method=method, block=32)
    D = np.asarray(geo.distances)
    nxt = np.asarray(geo.next_hop)
    np.testing.assert_allclose(D[np.isfinite(D)], _scipy(W)[np.isfinite(D)], rtol=1e-12)
    i, j = np.nonzero(np.isfinite(D) & ~np.eye(130, dtype=bool))
    k = nxt[i, j]
    np.testing.assert_allclose(W[i, k] + D[k, j], D[i, j], rtol=1e-12)
    assert np.all(nxt[~np.isfinite(D)] == -1)
    assert np.all(np.diag(nxt) == np.arange(130))


@pytest.mark.data
def test_real_float32_paths_have_no_cycles(data_dir):
    """float32 rounding ties must not create next-hop cycles (seen once on AnimFace)."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    pos, _ = fx.clean_frames(seq.positions[::3])
    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(pos, jnp.float32)))
    geo = fx.geodesic_distances(fx.epsilon_graph(P, 1.25 * float(fx.connecting_threshold(P))))
    n = len(pos)
    for i in range(0, n, 25):
        for j in range(0, n, 7):
            path = fx.shortest_path(geo, i, j)
            assert path[0] == i and path[-1] == j


# --- issue 31: the folded (undirected) Floyd and the next-hop search ---------------------


def _path_length(W, path):
    return sum(W[a, b] for a, b in zip(path[:-1], path[1:], strict=True))


@pytest.mark.parametrize(
    ("n", "q", "block"), [(5, 0.5, None), (40, 0.1, 8), (150, 0.05, 16), (301, 0.03, None)]
)
def test_folded_floyd_matches_scipy(rng, n, q, block):
    """Upper tiles only (paired tile rows, padding to an even tile count), connected or
    not: equal to scipy's Dijkstra, unreachable pairs inf, the result symmetric."""
    P, W, _ = _graph(rng, n, q)
    D = np.asarray(fx.floyd_warshall(W, method="blocked", block=block, symmetric=True))
    ref = _scipy(W)
    np.testing.assert_array_equal(np.isinf(D), np.isinf(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(D[fin], ref[fin], rtol=1e-12)
    np.testing.assert_array_equal(D, D.T)


def test_folded_floyd_column_groups(rng, monkeypatch):
    """A strip cut into several column groups (as past ~1 MiB) gives the same distances."""
    from fxspace.expression import _floyd_fold

    monkeypatch.setattr(_floyd_fold, "_FOLD_GROUP_BYTES", 3 * 8 * 8 * 8)  # 3 slots a group
    P, W, _ = _graph(rng, 123, 0.06)  # a shape no other test compiles
    _, _, groups, per = _floyd_fold._fold_layout(16, 8, 8)
    assert groups > 1 and per == 3
    D = np.asarray(fx.floyd_warshall(W, method="blocked", block=8, symmetric=True))
    ref = _scipy(W)
    fin = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(D), fin)
    np.testing.assert_allclose(D[fin], ref[fin], rtol=1e-12)


def test_symmetry_detected_and_asserted(rng):
    """``symmetric=None`` folds a concrete undirected graph (same distances as the general
    kernel), keeps a directed one general; ``True`` reads the upper triangle only."""
    from fxspace.expression._geodesic import _is_symmetric

    P, W, _ = _graph(rng, 260, 0.08)
    assert _is_symmetric(jnp.asarray(W), None) and not _is_symmetric(jnp.asarray(W), False)
    general = np.asarray(fx.floyd_warshall(W, method="blocked", symmetric=False))
    np.testing.assert_allclose(fx.floyd_warshall(W), general, rtol=1e-12)
    Wd = W.copy()
    Wd[3, 7] = np.inf if np.isfinite(Wd[3, 7]) else 0.5
    assert not _is_symmetric(jnp.asarray(Wd), None)
    ref = sp_shortest(np.where(np.isinf(Wd), 0, Wd), directed=True)
    np.testing.assert_allclose(fx.floyd_warshall(Wd), ref, rtol=1e-12)
    upper = np.triu(Wd) + np.triu(Wd, 1).T  # the upper triangle, mirrored
    np.testing.assert_allclose(
        fx.floyd_warshall(Wd, method="blocked", symmetric=True), _scipy(upper), rtol=1e-12
    )


def test_folded_jit_vmap_grad(rng):
    """Traced graphs take the folded kernel when told; vmap and grad still work."""
    P, W, _ = _graph(rng, 70, 0.1)
    fw = jax.jit(lambda w: fx.floyd_warshall(w, method="blocked", block=16, symmetric=True))
    np.testing.assert_allclose(fw(W), _scipy(W), rtol=1e-12)
    Ws = jax.vmap(lambda t: fx.epsilon_graph(P, t))(jnp.asarray([0.8, 1.5]))
    Ds = jax.vmap(fw)(Ws)
    for k in range(2):
        np.testing.assert_allclose(Ds[k], _scipy(np.asarray(Ws[k])), rtol=1e-12)
    geo = fx.geodesic_distances(W)
    i, j = 0, int(np.argmax(np.where(np.isfinite(geo.distances[0]), geo.distances[0], -1)))
    g = np.asarray(jax.grad(lambda w: fw(w)[i, j])(jnp.asarray(W)))
    assert np.all(np.tril(g, -1) == 0)  # folded: every edge weight is read from the upper half
    path = fx.shortest_path(geo, i, j)
    expect = np.zeros_like(W)
    for a, b in zip(path[:-1], path[1:], strict=True):
        expect[min(a, b), max(a, b)] += 1
    off = ~np.eye(len(W), dtype=bool)  # the diagonal is the constant 0 of epsilon_graph
    np.testing.assert_allclose(g[off], expect[off], atol=1e-12)


def _check_hops(W, nxt, ref):
    """Every next hop is an edge strictly closer to j on a shortest path (scipy's ref)."""
    n = len(W)
    i, j = np.nonzero(np.isfinite(ref) & (ref > 0))
    k = nxt[i, j]
    assert np.all(k >= 0)
    np.testing.assert_allclose(W[i, k] + ref[k, j], ref[i, j], rtol=1e-10)
    assert np.all(ref[k, j] < ref[i, j])
    assert np.all(nxt[~np.isfinite(ref)] == -1) and np.all(np.diag(nxt) == np.arange(n))


@pytest.mark.parametrize("shuffle", [False, True])
@pytest.mark.parametrize("chunk", [16, 7])
def test_next_hops_rebuild_geodesic_paths(rng, shuffle, chunk):
    """Blocks of consecutive rows (the union of their neighbours; a ragged last block; a
    shuffled vertex order, where the unions are large) give valid hops whose paths have
    scipy's geodesic length, with no cycles."""
    P, W, _ = _graph(rng, 181, 0.06)
    if shuffle:
        perm = rng.permutation(len(W))
        W = W[np.ix_(perm, perm)]
    ref = _scipy(W)
    D = fx.floyd_warshall(W)
    nxt = np.asarray(fx.next_hops(W, D, chunk=chunk))
    _check_hops(W, nxt, ref)
    geo = fx.Geodesics(D, jnp.asarray(nxt))
    for i, j in rng.integers(0, len(W), (40, 2)):
        if np.isfinite(ref[i, j]):
            path = fx.shortest_path(geo, i, j)
            np.testing.assert_allclose(_path_length(W, path), ref[i, j], rtol=1e-10)


def test_next_hops_directed(rng):
    n = 60
    W = np.where(rng.random((n, n)) < 0.08, rng.random((n, n)) + 0.1, np.inf)
    np.fill_diagonal(W, 0)
    ref = sp_shortest(np.where(np.isinf(W), 0, W), directed=True)
    geo = fx.geodesic_distances(W)
    _check_hops(W, np.asarray(geo.next_hop), ref)


def test_next_hops_repeated_frames_do_not_cycle(rng):
    """Zero-weight edges between repeated frames tie every detour through the copy: each hop
    must still get strictly closer (the old argmin could bounce between two copies)."""
    X = rng.standard_normal((50, 3))
    X = np.concatenate([X, X[:10], X[:5]])  # copies: P = 0 between them
    P = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    W = np.asarray(fx.epsilon_graph(P, 1.3 * float(fx.connecting_threshold(P))))
    geo = fx.geodesic_distances(W)
    D, nxt = np.asarray(geo.distances), np.asarray(geo.next_hop)
    off = np.where(np.eye(len(W), dtype=bool), np.inf, W)  # zero weights stay edges
    ref = sp_shortest(csgraph_from_dense(off, null_value=np.inf), directed=False)
    np.testing.assert_allclose(D, ref, rtol=1e-12)
    _check_hops(W, nxt, ref)
    assert nxt[0, 50] == 50 and nxt[50, 0] == 0  # a frame and its copy: one hop
    for i in range(len(W)):
        for j in range(0, len(W), 3):
            path = fx.shortest_path(geo, i, j)
            np.testing.assert_allclose(_path_length(W, path), ref[i, j], rtol=1e-10, atol=1e-12)


def test_next_hops_max_degree_keeps_nearest(rng):
    """``max_degree`` at or above the largest degree changes nothing; below, hops use the
    nearest neighbours only (and remain edges)."""
    P, W, _ = _graph(rng, 80, 0.15)
    D = fx.floyd_warshall(W)
    full = np.asarray(fx.next_hops(W, D))
    deg = int((np.isfinite(W).sum(1) - 1).max())
    np.testing.assert_array_equal(np.asarray(fx.next_hops(W, D, max_degree=deg)), full)
    few = np.asarray(fx.next_hops(W, D, max_degree=3))
    i, j = np.nonzero(few >= 0)
    assert np.all(np.isfinite(W[i, few[i, j]]))


def test_next_hops_jit_vmap(rng):
    P, W, _ = _graph(rng, 50, 0.2)
    Ws = jax.vmap(lambda t: fx.epsilon_graph(P, t))(jnp.asarray([0.9, 1.6]))
    geos = jax.vmap(fx.geodesic_distances)(Ws)
    for k in range(2):
        Wk = np.asarray(Ws[k])
        _check_hops(Wk, np.asarray(geos.next_hop[k]), _scipy(Wk))
    one = jax.jit(fx.geodesic_distances)(W)
    np.testing.assert_array_equal(one.next_hop, fx.geodesic_distances(W).next_hop)


@pytest.mark.data
def test_real_capture_folded_and_hops_vs_scipy(data_dir):
    """AnimFace cheeks take (every 3rd frame) at the connecting ε, float32 as the
    benchmark runs it: folded distances within 1e-6 of scipy's float64 Dijkstra, every
    next hop on a shortest path within float32 rounding and strictly closer."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    pos, _ = fx.clean_frames(seq.positions[::3])
    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(pos, jnp.float32)))
    W = fx.epsilon_graph(P, 1.05 * float(fx.connecting_threshold(P)))
    geo = fx.geodesic_distances(W)
    Wn = np.asarray(W, np.float64)
    ref = _scipy(Wn)
    D = np.asarray(geo.distances, np.float64)
    fin = ref > 0
    assert np.all(np.isfinite(ref))
    assert np.max(np.abs(D[fin] - ref[fin]) / ref[fin]) < 1e-6
    nxt = np.asarray(geo.next_hop)
    i, j = np.nonzero(fin)
    k = nxt[i, j]
    assert np.max(np.abs(Wn[i, k] + ref[k, j] - ref[i, j]) / ref[i, j]) < 1e-6
    assert np.all(ref[k, j] < ref[i, j])
