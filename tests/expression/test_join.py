"""`join_components`: a k-NN graph in pieces (several takes) joined at the closest frames
between pieces, against brute force (scipy's cdist + minimum spanning tree)."""

import numpy as np
import pytest
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial.distance import cdist

import fxspace as fx
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression import join_components, neighbourhood_graph_blocks, sparse_components
from fxspace.synthetic import synthetic_face


def _takes(scales=(1.0, 1.25, 1.6), frames=300, seed=0):
    """Takes of one synthetic performance on faces of different sizes: each take's frames
    nearer one another than any frame of another take (a graph in pieces)."""
    face = synthetic_face(n_markers=16, n_frames=frames, seed=seed)
    pos = np.asarray(face.sequence.positions)
    return np.concatenate([pos * s for s in scales]).astype(np.float64)


def _features(pos):
    return np.asarray(fx.distance_features(pos), np.float64)


def _brute_mst(F, labels):
    """Total length of the minimum spanning tree over the pieces (closest pairs, cdist)."""
    n = labels.max() + 1
    W = np.zeros((n, n))
    for a in range(n):
        for b in range(a + 1, n):
            W[a, b] = cdist(F[labels == a], F[labels == b]).min()
    return minimum_spanning_tree(W).sum()


def _edges(g):
    idx, w = np.asarray(g.indices), np.asarray(g.weights)
    ok = np.isfinite(w)
    rows = np.repeat(np.arange(len(idx)), idx.shape[1]).reshape(idx.shape)
    return {(int(i), int(j)): float(x) for i, j, x in zip(rows[ok], idx[ok], w[ok], strict=True)}


def test_pieces_joined_by_the_closest_pairs():
    pos = _takes()
    g = neighbourhood_graph_blocks(pos, k=6)
    n, labels = sparse_components(g)
    assert n == 3
    joined, joins = join_components(g, pos)
    assert sparse_components(joined)[0] == 1
    assert joins.frames.shape == (2, 2) and joins.sizes.tolist() == [300, 300, 300]
    F = _features(pos)
    # each added edge is an exact feature distance between two pieces ...
    for (i, j), d in zip(joins.frames, joins.lengths, strict=True):
        assert labels[i] != labels[j]
        np.testing.assert_allclose(d, np.linalg.norm(F[i] - F[j]), rtol=1e-6)
    # ... and together they are the minimum spanning tree over the pieces
    np.testing.assert_allclose(joins.lengths.sum(), _brute_mst(F, labels), rtol=1e-6)
    # every edge already there is kept, with its length; the new ones both ways
    before, after = _edges(g), _edges(joined)
    assert all(after[e] == w for e, w in before.items())
    for (i, j), d in zip(joins.frames, joins.lengths, strict=True):
        assert after[(int(i), int(j))] == after[(int(j), int(i))] == np.float64(d)
    assert len(after) == len(before) + 2 * len(joins.lengths)
    # laid out as a graph packed from all its edges at once
    from fxspace.expression._sparse import _pack

    idx, w = np.asarray(g.indices), np.asarray(g.weights)
    rows = np.concatenate([np.repeat(np.arange(len(idx)), idx.shape[1]), joins.frames[:, 0]])
    cols = np.concatenate([idx.ravel(), joins.frames[:, 1]])
    ref = _pack(rows, cols, np.concatenate([w.ravel(), joins.lengths]), len(idx), w.dtype)
    np.testing.assert_array_equal(np.asarray(joined.indices), np.asarray(ref.indices))
    np.testing.assert_array_equal(np.asarray(joined.weights), np.asarray(ref.weights))


@pytest.mark.parametrize("queries, pairs, candidates", [(1, 1, 8), (4, 2, 8), (2, 1, 16)])
def test_a_poor_first_pair_is_improved_to_the_closest(queries, pairs, candidates):
    """From one queried frame's nearest, moving one end at a time to the frame nearest the
    other reaches the closest pairs (without it: 1.8–3.6 % longer here)."""
    pos = _takes()
    g = neighbourhood_graph_blocks(pos, k=6)
    _, labels = sparse_components(g)
    _, joins = join_components(g, pos, queries=queries, pairs=pairs, candidates=candidates)
    np.testing.assert_allclose(joins.lengths.sum(), _brute_mst(_features(pos), labels),
                               rtol=1e-6)  # fmt: skip


def test_few_frame_pieces_use_the_tree_of_all_frames():
    """A piece of a few frames (an outlier's) is searched in the tree of all frames."""
    pos = _takes(scales=(1.0, 1.8), frames=300)
    pos = np.concatenate([pos, pos[:3] * 2.5])  # three frames far from both takes
    g = neighbourhood_graph_blocks(pos, k=2)
    n, labels = sparse_components(g)
    assert n >= 3 and np.bincount(labels).min() <= 3
    joined, joins = join_components(g, pos)
    assert sparse_components(joined)[0] == 1 and len(joins.lengths) == n - 1
    np.testing.assert_allclose(joins.lengths.sum(), _brute_mst(_features(pos), labels),
                               rtol=1e-6)  # fmt: skip


def test_connected_graph_is_returned_as_it_is():
    pos = _takes(scales=(1.0,))
    g = neighbourhood_graph_blocks(pos, k=6)
    joined, joins = join_components(g, pos)
    assert joined is g and joins.frames.shape == (0, 2) and joins.sizes.tolist() == [300]


def test_too_many_pieces_and_bad_input_are_named():
    pos = _takes()
    g = neighbourhood_graph_blocks(pos, k=6)
    with pytest.raises(DisconnectedGraphError, match="max_components = 2.*raise k"):
        join_components(g, pos, max_components=2)
    with pytest.raises(FxspaceError, match="positions must be the graph's"):
        join_components(g, pos[:-1])
    with pytest.raises(FxspaceError, match="candidates"):
        join_components(g, pos, candidates=0)


def test_real_takes_joined_near_their_closest_pairs(data_dir):
    """The shared AnimFace takes (three captures, each its own piece or two touching)
    resampled:
    joined, the joins within 1 % of the brute-force minimum spanning tree over them."""
    from fxspace.datasets import FaceData, load_face

    face = load_face(FaceData(source="animface", target_frames=6000), 0)
    pos = np.asarray(face.positions, np.float64)
    g = neighbourhood_graph_blocks(pos, k=10)
    n, labels = sparse_components(g)
    assert 2 <= n <= len(face.take_names) == 3  # two takes may touch at this k
    joined, joins = join_components(g, pos)
    assert sparse_components(joined)[0] == 1 and len(joins.lengths) == n - 1
    best = _brute_mst(_features(pos), labels)
    assert best * (1 - 1e-9) <= joins.lengths.sum() <= 1.01 * best


def test_added_edges_laid_out_as_a_packed_graph():
    """Edges added to full rows widen the graph by a column; the rows they touch come out
    as `graph_from_dense` lays out the whole graph."""
    from fxspace.expression._sparse import _add_edges

    W = np.full((5, 5), np.inf)
    for a, b, d in [(0, 1, 1.0), (1, 2, 2.0), (2, 3, 1.5), (3, 4, 0.5)]:
        W[a, b] = W[b, a] = d
    g = fx.graph_from_dense(W)
    assert g.indices.shape == (5, 2)
    got = _add_edges(g, np.array([1, 0]), np.array([3, 4]), np.array([2.5, 7.0]))
    W[1, 3] = W[3, 1] = 2.5
    W[0, 4] = W[4, 0] = 7.0
    ref = fx.graph_from_dense(W)
    assert got.indices.shape == (5, 3)
    np.testing.assert_array_equal(np.asarray(got.indices), np.asarray(ref.indices))
    np.testing.assert_array_equal(np.asarray(got.weights), np.asarray(ref.weights))
