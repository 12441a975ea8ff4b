import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

import fxspace as fx
from fxspace.errors import DisconnectedGraphError, FxspaceError


def _space(rng, n=160, factor=1.4, dim=3):
    X = rng.standard_normal((n, dim))
    P = np.asarray(fx.pairwise_distances(jnp.asarray(X)))
    W = np.asarray(fx.epsilon_graph(P, float(fx.connecting_threshold(P)) * factor))
    return X, W


def test_landmark_geodesics_equal_scipy_dijkstra(rng):
    _, W = _space(rng)
    g = fx.graph_from_dense(W)
    lm = np.array([0, 17, 99, 159])
    ref = dijkstra(np.where(np.isinf(W), 0, W), directed=False, indices=lm)
    for method in ("dijkstra", "relax"):
        geo = fx.landmark_geodesics(g, lm, method=method)
        np.testing.assert_allclose(np.asarray(geo.distances), ref, rtol=1e-12)
        np.testing.assert_array_equal(np.asarray(geo.landmarks), lm)


def test_farthest_point_rows_identical_to_scipy_on_the_same_landmarks(rng):
    """The fast path (symmetric graph, scipy's directed search, one source a step) gives
    bit-identical rows to scipy's undirected Dijkstra from all the landmarks at once."""
    from fxspace.expression import to_scipy

    X = rng.standard_normal((600, 3)).cumsum(axis=0) * 0.1
    g = fx.neighbourhood_graph(jnp.asarray(X), k=6, reduce_dim=None)
    geo = fx.farthest_point_landmarks(g, 12)
    lm = np.asarray(geo.landmarks)
    ref = dijkstra(to_scipy(g), directed=False, indices=lm)
    np.testing.assert_array_equal(np.asarray(geo.distances), ref.astype(g.weights.dtype))
    again = fx.landmark_geodesics(g, lm, method="dijkstra")
    np.testing.assert_array_equal(np.asarray(again.distances), np.asarray(geo.distances))


def test_asymmetric_graph_keeps_undirected_semantics(rng):
    from fxspace.expression import NeighbourGraph, to_scipy
    from fxspace.expression._sparse import dijkstra_csr

    idx = jnp.asarray([[1, 0], [2, 1], [2, 2]], jnp.int32)  # 0-1, 1-2 given one way only
    w = jnp.asarray([[1.0, jnp.inf], [2.5, jnp.inf], [jnp.inf, jnp.inf]])
    g = NeighbourGraph(idx, w)
    assert dijkstra_csr(g)[1] is False
    geo = fx.landmark_geodesics(g, np.array([0, 2]), method="dijkstra")
    ref = dijkstra(to_scipy(g), directed=False, indices=[0, 2])
    np.testing.assert_array_equal(np.asarray(geo.distances), ref)
    np.testing.assert_array_equal(ref, [[0.0, 1.0, 3.5], [3.5, 2.5, 0.0]])


def test_relaxation_is_jittable_and_counts_sweeps(rng):
    from fxspace.expression._landmark import _relax

    _, W = _space(rng, 80)
    g = fx.graph_from_dense(W)
    D, steps = jax.jit(_relax, static_argnames="max_steps")(
        g.indices, g.weights, jnp.arange(3), max_steps=80
    )
    ref = dijkstra(np.where(np.isinf(W), 0, W), directed=False, indices=[0, 1, 2])
    np.testing.assert_allclose(np.asarray(D), ref, rtol=1e-12)
    assert 1 <= int(steps) < 80


def test_landmark_mds_equals_classical_mds_with_every_frame(rng):
    _, W = _space(rng)
    D = fx.floyd_warshall(W)
    cm = fx.classical_mds(D, dim=3, method="eigh")
    geo = fx.landmark_geodesics(fx.graph_from_dense(W), np.arange(W.shape[0]))
    lm = fx.landmark_mds(geo, dim=3)
    np.testing.assert_allclose(np.asarray(lm.eigenvalues), np.asarray(cm.eigenvalues), rtol=1e-9)
    np.testing.assert_allclose(np.asarray(lm.embedding), np.asarray(cm.embedding), atol=1e-9)
    assert bool(lm.converged) and int(lm.num_steps) == 0


def test_landmark_mds_of_a_euclidean_configuration_is_exact(rng):
    # complete graph of points in the plane: any 3+ landmarks in general position
    # recover the configuration up to a rigid motion (de Silva & Tenenbaum, Thm. 1)
    X = rng.standard_normal((60, 2))
    P = np.asarray(fx.pairwise_distances(jnp.asarray(X)))
    geo = fx.landmark_geodesics(fx.graph_from_dense(P), np.arange(0, 60, 6))
    Y = np.asarray(fx.landmark_mds(geo, dim=2).embedding)
    E = np.sqrt(((Y[:, None] - Y[None]) ** 2).sum(-1))
    np.testing.assert_allclose(E, P, atol=1e-9)


def test_out_of_sample_placement_of_a_landmark_is_its_coordinates(rng):
    _, W = _space(rng)
    geo = fx.farthest_point_landmarks(fx.graph_from_dense(W), 12)
    D = np.asarray(geo.distances)
    lm = np.asarray(geo.landmarks)
    basis = fx.expression.landmark_basis(D[:, lm], dim=2)
    own = np.asarray(fx.place_frames(basis, D[:, lm].T))  # every landmark placed
    emb = np.asarray(fx.landmark_mds(geo, dim=2).embedding)
    np.testing.assert_allclose(own, emb[lm], atol=1e-10)
    # and the landmark coordinates are the classical MDS of the L x L block
    cm = fx.classical_mds(D[:, lm], dim=2, method="eigh")
    np.testing.assert_allclose(own, np.asarray(cm.embedding), atol=1e-9)


def test_farthest_point_landmarks_max_min(rng):
    _, W = _space(rng)
    D = np.asarray(fx.floyd_warshall(W))
    geo = fx.farthest_point_landmarks(fx.graph_from_dense(W), 6, start=5)
    lm = np.asarray(geo.landmarks)
    assert lm[0] == np.argmax(D[5]) and len(set(lm.tolist())) == 6
    for t in range(1, 6):
        mind = D[lm[:t]].min(axis=0)
        assert np.isclose(mind[lm[t]], mind.max())
    np.testing.assert_allclose(np.asarray(geo.distances), D[lm], rtol=1e-12)


def test_memory_is_order_T_times_L(rng):
    X = rng.standard_normal((2000, 3))
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    geo = fx.farthest_point_landmarks(g, 16)
    mds = fx.landmark_mds(geo, dim=2)
    T, L = 2000, 16
    assert g.indices.shape[0] == T and g.indices.shape[1] < 40  # O(T·K), no T x T
    assert geo.distances.shape == (L, T)
    assert mds.embedding.shape == (T, 2)
    biggest = max(a.size for a in (*g, *geo, *mds) if hasattr(a, "size"))
    assert biggest <= T * 40  # nothing of size T² = 4e6
    r = float(fx.landmark_score(geo, mds.embedding))
    assert 0.5 < r <= 1.0


def test_landmark_score_equals_pearson_on_the_landmark_pairs(rng):
    _, W = _space(rng)
    D = np.asarray(fx.floyd_warshall(W))
    geo = fx.landmark_geodesics(fx.graph_from_dense(W), np.array([2, 50, 120]))
    Y = np.asarray(fx.landmark_mds(geo, dim=2).embedding)
    lm = np.asarray(geo.landmarks)
    E = np.sqrt(((Y[lm][:, None] - Y[None]) ** 2).sum(-1))
    mask = lm[:, None] != np.arange(len(Y))[None]
    ref = np.corrcoef(D[lm][mask], E[mask])[0, 1]
    assert np.isclose(float(fx.landmark_score(geo, Y)), ref, rtol=1e-10)


def test_expression_space_landmark_route(rng):
    from fxspace.synthetic import synthetic_face

    pos = synthetic_face(n_frames=120, seed=1, n_markers=20).sequence.positions
    dense = fx.expression_space(pos, 1e9, route="dense", paths=False, mds_method="eigh")
    es = fx.expression_space(pos, 1e9, route="landmark", landmarks=120, neighbours=119)
    assert isinstance(es, fx.ExpressionSpace) and isinstance(es.mds, fx.MDSResult)
    assert es.pairwise is None and isinstance(es.graph, fx.NeighbourGraph)
    assert es.geodesics.distances.shape == (120, 120)
    # complete graph, every frame a landmark: classical MDS of the same distances
    np.testing.assert_allclose(
        np.abs(np.asarray(es.embedding)), np.abs(np.asarray(dense.embedding)), atol=1e-6
    )


def test_disconnected_and_bad_arguments(rng):
    X = np.concatenate([rng.standard_normal((30, 2)), rng.standard_normal((30, 2)) + 50])
    g = fx.neighbourhood_graph(X, k=4, reduce_dim=None)
    with pytest.raises(DisconnectedGraphError, match="not reachable"):
        fx.farthest_point_landmarks(g, 4)
    with pytest.raises(FxspaceError, match="landmarks"):
        fx.landmark_geodesics(g, [60])
    with pytest.raises(FxspaceError, match="NeighbourGraph"):
        fx.landmark_geodesics(np.zeros((3, 3)), [0])  # type: ignore[arg-type]
    with pytest.raises(DisconnectedGraphError):
        fx.landmark_mds(fx.landmark_geodesics(g, [0, 1, 2, 40]), dim=2)
    with pytest.raises(FxspaceError, match="landmark"):
        fx.expression_space(None, 1.0, pairwise=np.zeros((4, 4)), route="landmark")
