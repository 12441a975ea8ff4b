"""A k-NN graph in pieces joined at its closest frames (Borůvka over the pieces: a
minimum spanning tree, as scikit-learn's Isomap joins components), the closest pair of
each two pieces searched in the graph's candidate space (`fxspace.expression._blocks`'
projection) and measured in exact features."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fxspace._progress import progress
from fxspace._validate import check_int, checked
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression._blocks import _AXES_SAMPLE, _block_features
from fxspace.expression._sparse import (
    NeighbourGraph,
    _add_edges,
    _principal_axes,
    sparse_components,
)

__all__ = ["Joins", "join_components"]


class Joins(NamedTuple):
    """The edges `join_components` added to a disconnected graph.

    - `frames`: ``(J, 2)`` int64, the two frames of each added edge (J = components − 1).
    - `lengths`: ``(J,)`` their lengths: exact marker-distance feature distances, as
      every other edge of the graph.
    - `sizes`: the components' sizes before joining, largest first.
    """

    frames: np.ndarray
    lengths: np.ndarray
    sizes: np.ndarray


def _projection(X, dim: int, block: int, dtype) -> np.ndarray:
    """``(T, dim)``: every frame's features on the principal axes of ≤ `_AXES_SAMPLE`
    frames' features (the graph's candidate space), the features formed a block at a
    time and dropped (never the whole ``(T, P)`` matrix)."""
    T = X.shape[0]
    rng = np.random.default_rng(0)
    sample = np.sort(rng.choice(T, min(T, _AXES_SAMPLE), replace=False))
    S = _block_features(X, sample, block)
    mean = S.mean(axis=0)
    axes = _principal_axes(S, min(int(dim), S.shape[1]))
    del S
    Z = np.empty((T, axes.shape[1]), axes.dtype)
    for s in range(0, T, block):
        Z[s : s + block] = (_block_features(X, np.arange(s, min(s + block, T)), block)
                            - mean) @ axes  # fmt: skip
    return np.ascontiguousarray(Z.astype(dtype, copy=False))


class _Piece:
    """Nearest-frame queries for one component ``c`` of a graph, in the projection Z:
    inside it and outside it (a tree of the frames outside for a large piece; for a
    few frames, the tree of all frames with theirs dropped)."""

    def __init__(self, Z, comp, c: int, tree, small: int):
        from scipy.spatial import cKDTree

        self.Z, self.comp, self.c, self.tree = Z, comp, c, tree
        self.inside = np.flatnonzero(comp == c)
        self.small = len(self.inside) <= small
        self.in_tree = cKDTree(Z[self.inside])
        if not self.small:
            self.outside = np.flatnonzero(comp != c)
            self.out_tree = cKDTree(Z[self.outside])

    def near_outside(self, rows: np.ndarray, num: int, bound: float = np.inf):
        """``(i, j, z)``: each of ``rows``'s ``num`` nearest frames outside the piece,
        those nearer than ``bound`` in the projection (a bound prunes the tree's search:
        frames of another take are far, and an unbounded search for them visits much of
        the tree)."""
        Z = self.Z
        if self.small:
            tree, k, outside = self.tree, min(len(Z), num + len(self.inside)), None
        else:
            tree, k, outside = self.out_tree, min(num, len(self.outside)), self.outside
        dz, jj = tree.query(Z[rows], k=k, workers=-1, distance_upper_bound=bound)
        dz, jj = dz.reshape(len(rows), -1), jj.reshape(len(rows), -1)
        ok = np.isfinite(dz)
        jj = np.where(ok, jj, 0)
        if outside is None:
            ok &= self.comp[jj] != self.c
        else:
            jj = outside[jj]
        ii = np.broadcast_to(rows[:, None], jj.shape)
        return ii[ok], jj[ok], dz[ok]

    def near_inside(self, j: int, num: int) -> np.ndarray:
        """The piece's ``num`` frames nearest frame ``j``."""
        _, ii = self.in_tree.query(self.Z[[j]], k=min(num, len(self.inside)))
        return self.inside[np.ravel(ii)]


def _exact(X, ii, jj, block: int, dtype) -> np.ndarray:
    """Exact feature distances of the pairs ``(ii[p], jj[p])`` (each pair's squares summed
    over a contiguous row, as the graph's edges)."""
    rows = np.unique(np.concatenate([ii, jj]))
    F = _block_features(X, rows, block).astype(dtype, copy=False)
    diff = F[np.searchsorted(rows, ii)] - F[np.searchsorted(rows, jj)]
    return np.sqrt(np.add.reduce(diff * diff, axis=1))


def _best_of(X, ii, jj, dz, pairs: int, block: int, dtype, best):
    """The shortest of the ``pairs`` candidate pairs nearest in the projection, measured
    exactly, or ``best`` when none is shorter."""
    if len(dz) == 0:
        return best
    near = np.argsort(dz, kind="stable")[:pairs]
    ii, jj = ii[near], jj[near]
    d = _exact(X, ii, jj, block, dtype)
    b = int(np.argmin(d))
    return min(best, (float(d[b]), int(ii[b]), int(jj[b])))


def _improve(X, piece: _Piece, best, num: int, block: int, dtype):
    """Move one end of the pair at a time to the frame nearest the other (among ``num``
    candidates measured exactly) until neither moves."""
    for _ in range(16):
        _, i, j = best
        ci = piece.near_inside(j, num)
        di = _exact(X, ci, np.full(len(ci), j), block, dtype)
        i = int(ci[np.argmin(di)])
        _, cj, _ = piece.near_outside(np.asarray([i]), num)
        dj = _exact(X, np.full(len(cj), i), cj, block, dtype)
        step = (float(np.min(dj)), i, int(cj[np.argmin(dj)]))
        if not step[0] < best[0]:
            break
        best = step
    return best


def _closest_pair(X, piece: _Piece, num: int, pairs: int, queries: int, block: int, dtype):
    """``(length, i, j)``: the closest pair from the piece to the rest that a search finds:
    a first pair from a few of its frames, improved one end at a time (`_improve`); then
    ≤ ``queries`` of its frames (evenly spaced), each one's ``num`` nearest outside it in
    the projection nearer than that pair (the projection's distances are lower bounds
    of the exact ones: no farther candidate can be shorter), the ``pairs`` nearest of
    them measured exactly, and the shortest improved again."""
    inside = piece.inside

    def spaced(n: int) -> np.ndarray:
        if len(inside) <= n:
            return inside
        return inside[np.linspace(0, len(inside) - 1, n).round().astype(np.int64)]

    few = spaced(min(queries, 64))
    best = _best_of(X, *piece.near_outside(few, min(num, 8)), pairs, block, dtype,
                    (np.inf, -1, -1))  # fmt: skip
    best = _improve(X, piece, best, num, block, dtype)
    found = _best_of(X, *piece.near_outside(spaced(queries), num, best[0] * (1 + 1e-6)),
                     pairs, block, dtype, best)  # fmt: skip
    return best if found == best else _improve(X, piece, found, num, block, dtype)


def _root(parent: np.ndarray, a: int) -> int:
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return int(a)


@checked
def join_components(
    graph: NeighbourGraph, positions, *, candidates: int = 64, pairs: int = 16384,
    queries: int = 4096, max_components: int = 256, reduce_dim: int = 8, block: int = 2048,
) -> tuple[NeighbourGraph, Joins]:  # fmt: skip
    """Join a disconnected k-NN graph's components at their closest frames.

    Several takes of one face, or a session's pauses, give a k-NN graph in pieces (each
    take's frames nearer one another than any frame of another take): no geodesic crosses
    from one to the next. As Isomap implementations do (scikit-learn's ``Isomap``), each
    piece is joined to its nearest other piece by one edge, the closest pair of frames
    between them, in rounds until one piece is left (Borůvka: a minimum spanning tree
    over the pieces, J = pieces − 1 edges). The pair is searched in the graph's candidate
    space (the features' principal axes, a lower bound of the exact distance): a first
    pair from a few of the piece's frames, improved one end at a time (each end moved to
    the frame nearest the other) until neither moves; then, from ``queries`` of its
    frames (evenly spaced), each one's ``candidates`` nearest outside it and nearer than
    that pair in the candidate space, the ``pairs`` nearest of those measured exactly,
    the shortest improved again. The search is not exhaustive (that is a brute-force
    pass over every pair of frames of two pieces): on small inputs it finds the closest
    pairs (the tests compare with scipy's ``cdist``), and on the AnimFace takes resampled
    to 6 000 and 12 000 frames it found them too (the test allows 1 %). Its length is the
    exact feature distance, as every edge's: the geodesics stay lengths of real steps
    between states, and a route from one take to another passes through that pair. Edges
    already there are kept.

    **Arguments:**

    - `graph`: a `NeighbourGraph` of ``positions`` (`neighbourhood_graph_blocks`).
    - `positions`: its ``(T, M, 3)`` frames (numpy or memory-mapped; the features are
      formed a block at a time).
    - `candidates`, `pairs`, `queries`: the search above.
    - `max_components`: more pieces than this is not a few takes but a graph too sparse
      (raise ``k``): a `DisconnectedGraphError` then.
    - `reduce_dim`, `block`: the candidate space's axes; frames formed at once.

    **Returns:** ``(graph, joins)``: the joined graph (the same graph when connected) and
    the `Joins` added (empty when none).

    **Example:** ``g, joins = fx.expression.join_components(g, positions)``
    """
    X = positions if isinstance(positions, np.memmap) else np.asarray(positions)
    T = graph.num_frames
    if X.ndim != 3 or X.shape[0] != T or X.shape[-1] != 3:
        raise FxspaceError(
            f"positions must be the graph's (frames = {T}, markers, 3) frames, got "
            f"shape {X.shape}"
        )
    candidates = check_int(candidates, "candidates", low=1)
    pairs = check_int(pairs, "pairs", low=1)
    queries = check_int(queries, "queries", low=1)
    max_components = check_int(max_components, "max_components", low=1)
    n_comp, comp = sparse_components(graph)
    sizes = np.sort(np.bincount(comp))[::-1]
    if n_comp == 1:
        return graph, Joins(np.empty((0, 2), np.int64), np.empty(0, np.float64), sizes)
    if n_comp > max_components:
        raise DisconnectedGraphError(
            f"the neighbourhood graph has {n_comp} connected components (sizes "
            f"{sizes[:10].tolist()}), more than max_components = {max_components}: not a "
            "few takes but a graph too sparse; raise k, or drop the isolated frames"
        )
    from scipy.spatial import cKDTree

    dtype = np.asarray(graph.weights).dtype
    Z = _projection(X, reduce_dim, block, dtype)
    tree = cKDTree(Z)
    added: list[tuple[int, int, float]] = []
    while n_comp > 1:
        best = [
            _closest_pair(X, _Piece(Z, comp, c, tree, small=64), candidates, pairs,
                          queries, block, dtype)  # fmt: skip
            for c in progress(range(n_comp), f"joining {n_comp} components", total=n_comp)
        ]
        parent = np.arange(n_comp)  # union-find over this round's components
        for d, i, j in sorted(best):
            a, b = _root(parent, comp[i]), _root(parent, comp[j])
            if a != b:
                parent[max(a, b)] = min(a, b)
                added.append((i, j, d))
        _, new = np.unique([_root(parent, c) for c in range(n_comp)], return_inverse=True)
        comp = new[comp]
        n_comp = int(new.max()) + 1
    a = np.asarray(added)
    ii, jj = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64)
    joined = _add_edges(graph, ii, jj, a[:, 2])
    return joined, Joins(a[:, :2].astype(np.int64), a[:, 2].astype(np.float64), sizes)
