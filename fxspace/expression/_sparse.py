"""Sparse neighbourhood graph without a dense T × T matrix (Tenenbaum et al. 2000, §Isomap).

The dense chain holds the ``(T, T)`` state distances; past a few thousand frames that no
longer fits (one float32 matrix is 10 GB at T = 50 000). Here each frame keeps only its
nearest neighbours, as a padded adjacency list `NeighbourGraph` (``(T, K)``
indices and weights, ``inf`` = padding), so memory is O(T·K).

Neighbour search, for features of many dimensions (``P = M(M−1)/2`` marker distances):

1. **candidates** in a low-dimensional principal subspace (the face's expressions span a
   handful of principal axes; the rest is measurement noise): ``C ≥ k`` nearest by brute
   force (chunked GEMM + ``top_k``, accelerator friendly) or a k-d tree (host, fast on a
   CPU at ~8 dimensions);
2. **refinement** with the exact distances in the full feature space, keeping the
   ``k`` nearest (and, with a threshold ε, only those within ε: the ε-graph capped at ``k``
   neighbours);
3. **symmetrisation** (an edge if either end chose it), as Isomap does.

Without the reduction (``reduce_dim=None``) the search is exact. Cost O(T·C·P) for the
refinement plus the candidate search (O(T²·d) brute force, ~O(T log T) for the tree).
"""

from __future__ import annotations

import mmap
import weakref
from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import check_index, checked
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression._paths import graph_lengths, graph_path, graph_steps, graph_toward

__all__ = [
    "NeighbourGraph",
    "neighbourhood_graph",
    "graph_from_dense",
    "KnnQuality",
    "knn_quality",
    "knn_recall",
    "to_scipy",
    "sparse_components",
    "check_sparse_connected",
    "sparse_shortest_path",
]


class NeighbourGraph(NamedTuple):
    """A weighted undirected graph as a padded adjacency list (memory O(T·K)).

    - `indices`: ``(T, K)`` int32 neighbour frames; padding slots point at the frame itself.
    - `weights`: ``(T, K)`` edge lengths; ``inf`` in padding slots.
    """

    indices: Int[Array, "n k"]
    weights: Float[Array, "n k"]

    @property
    def num_frames(self) -> int:
        return int(self.indices.shape[0])

    @property
    def degree(self) -> np.ndarray:
        """Number of neighbours of each frame (host array)."""
        return np.sum(np.isfinite(np.asarray(self.weights)), axis=1)

    def dijkstra_csr(self):
        """``(csr, directed)`` for scipy's Dijkstra on this graph (see `dijkstra_csr`)."""
        return dijkstra_csr(self)

    # the paths interface of navigation (fxspace.expression._paths.Paths)
    def path(self, i: int, j: int, limit: float | None = None) -> np.ndarray:
        """Frames of a shortest path i → j (Dijkstra into j, stopped at ``limit``: the
        path's length when known; an edge that long is the path)."""
        return graph_path(self, i, j, limit)

    def lengths(self, i, j) -> np.ndarray:
        """Geodesic lengths of the pairs ``(i[p], j[p])`` (one Dijkstra per distinct i)."""
        return graph_lengths(self, i, j)

    def toward(self, targets) -> tuple[np.ndarray, np.ndarray]:
        """``(dist, hop)`` ``(k, T)``: each frame's distance to ``targets[r]`` and its next
        frame on a shortest path there (the target itself at it, -1 when unreachable)."""
        return graph_toward(self, targets)

    def steps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(i, j, length)`` of the edges i < j that are themselves shortest paths."""
        return graph_steps(self)


def _pack(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, n: int, dtype) -> NeighbourGraph:
    """Symmetrise an edge list (keep the shortest copy of each edge) and pad it to (n, K)."""
    r = np.concatenate([rows, cols])
    c = np.concatenate([cols, rows])
    v = np.concatenate([vals, vals])
    keep = (r != c) & np.isfinite(v)
    r, c, v = r[keep].astype(np.int64), c[keep].astype(np.int64), v[keep]
    key = r * n + c
    order = np.argsort(key, kind="stable")  # one int64 key: ~4x faster than a lexsort
    key, v = key[order], v[order]
    first = np.ones(key.size, bool)
    first[1:] = key[1:] != key[:-1]
    starts = np.flatnonzero(first)
    v = np.minimum.reduceat(v, starts) if v.size else v  # the shortest copy of each edge
    key = key[starts]
    r, c = key // n, key % n
    deg = np.bincount(r, minlength=n)
    K = max(int(deg.max()) if deg.size else 0, 1)
    start = np.concatenate([[0], np.cumsum(deg)[:-1]])
    slot = np.arange(r.size) - start[r]
    idx = np.repeat(np.arange(n, dtype=np.int32)[:, None], K, axis=1)
    w = np.full((n, K), np.inf, dtype)
    idx[r, slot] = c
    w[r, slot] = v
    return NeighbourGraph(jnp.asarray(idx), jnp.asarray(w))


def _add_edges(graph: NeighbourGraph, i, j, d) -> NeighbourGraph:
    """``graph`` with the undirected edges ``(i[p], j[p])`` of length ``d[p]`` added (none
    already there), laid out as `_pack` lays out the whole (each row's neighbours in
    column order, then padding): only the rows they touch are rebuilt, one column added
    where a row is full."""
    idx, w = np.asarray(graph.indices), np.asarray(graph.weights)
    rows = np.concatenate([i, j]).astype(np.int64)
    cols = np.concatenate([j, i]).astype(np.int64)
    vals = np.concatenate([d, d]).astype(w.dtype)
    deg = np.isfinite(w).sum(axis=1)
    touched = np.unique(rows)
    K = max(idx.shape[1], int((deg[touched] + np.bincount(rows)[touched]).max()))
    if K > idx.shape[1]:
        pad = K - idx.shape[1]
        idx = np.concatenate([idx, np.repeat(np.arange(len(idx), dtype=idx.dtype)[:, None],
                                             pad, axis=1)], axis=1)  # fmt: skip
        w = np.concatenate([w, np.full((len(w), pad), np.inf, w.dtype)], axis=1)
    else:
        idx, w = idx.copy(), w.copy()
    for r in touched:
        n = deg[r]
        c = np.concatenate([idx[r, :n], cols[rows == r]])
        v = np.concatenate([w[r, :n], vals[rows == r]])
        o = np.argsort(c, kind="stable")
        idx[r], w[r] = r, np.inf
        idx[r, : len(c)], w[r, : len(c)] = c[o], v[o]
    return NeighbourGraph(jnp.asarray(idx), jnp.asarray(w))


def graph_from_dense(graph: Float[Array, "n n"]) -> NeighbourGraph:
    """The `NeighbourGraph` of a dense graph (``inf`` = no edge), e.g. of
    `fxspace.epsilon_graph` — for tests and for small inputs."""
    W = np.asarray(graph)
    if W.ndim != 2 or W.shape[0] != W.shape[1]:
        raise FxspaceError(f"graph must be a square (n, n) matrix, got shape {W.shape}")
    r, c = np.nonzero(np.isfinite(W) & ~np.eye(len(W), dtype=bool))
    return _pack(r, c, W[r, c], len(W), W.dtype)


@checked
def to_scipy(graph: NeighbourGraph):
    """The graph as a ``scipy.sparse.csr_matrix`` (for ``scipy.sparse.csgraph``)."""
    from scipy.sparse import csr_matrix

    idx = np.asarray(graph.indices)
    w = np.asarray(graph.weights)
    n = idx.shape[0]
    ok = np.isfinite(w)
    rows = np.repeat(np.arange(n), idx.shape[1]).reshape(idx.shape)[ok]
    return csr_matrix((w[ok], (rows, idx[ok])), shape=(n, n))


@checked
def dijkstra_csr(graph: NeighbourGraph):
    """``(csr, directed)`` for ``scipy.sparse.csgraph.dijkstra`` on this graph, fastest form.

    scipy's ``directed=False`` walks the matrix and its transpose for every source (about
    twice the work of ``directed=True``). A symmetric matrix gives the same distances either
    way (each ``d[v] = min_u d[u] + w_uv`` is an exact minimum), so a symmetric graph — every
    `neighbourhood_graph` is — is passed as float64 with ``directed=True`` (validated and
    converted once, not per call); an asymmetric one keeps ``directed=False``. The
    answer is kept while the graph's two arrays live, so a route's many searches build it
    once; treat it as read-only.
    """
    key = (id(graph.indices), id(graph.weights))
    hit = _CSR_CACHE.get(key)
    if hit is not None and hit[0]() is graph.indices and hit[1]() is graph.weights:
        return hit[2]
    csr = to_scipy(graph).astype(np.float64)
    csr.sort_indices()
    symmetric = (csr != csr.T).nnz == 0
    out = (csr, bool(symmetric))  # directed=True is exact on a symmetric matrix
    try:  # kept while the graph's arrays live (a route asks once per link)
        refs = tuple(weakref.ref(a, lambda _, k=key: _CSR_CACHE.pop(k, None))
                     for a in (graph.indices, graph.weights))  # fmt: skip
    except TypeError:  # arrays without weak references: not cached
        return out
    _CSR_CACHE[key] = (*refs, out)
    return out


_CSR_CACHE: dict = {}  # (id(indices), id(weights)) -> (weakref, weakref, (csr, directed))


def _principal_axes(F: np.ndarray, dim: int, sample: int = 20000, seed: int = 0) -> np.ndarray:
    """Top ``dim`` principal axes ``(P, dim)`` of the rows of F (from ≤ ``sample`` rows),
    by randomised subspace iteration (Halko et al. 2011): O(n·P·dim), no P × P matrix."""
    rng = np.random.default_rng(seed)
    rows = F if len(F) <= sample else F[rng.choice(len(F), sample, replace=False)]
    X = (rows - rows.mean(axis=0)).astype(np.float32)
    Q = X @ rng.standard_normal((X.shape[1], min(dim + 10, X.shape[1]))).astype(np.float32)
    for _ in range(4):
        Q, _ = np.linalg.qr(Q)
        Q, _ = np.linalg.qr(X @ (X.T @ Q))
    _, _, Vt = np.linalg.svd(Q.T @ X, full_matrices=False)
    return np.ascontiguousarray(Vt[:dim].T).astype(F.dtype)


@partial(jax.jit, static_argnames=("num", "chunk"))
def _brute_candidates(Z: Array, num: int, chunk: int) -> Array:
    """``num`` nearest rows of Z (Euclidean, self excluded) by chunked GEMM + ``top_k``."""
    n = Z.shape[0]
    sq = jnp.sum(Z * Z, axis=1)
    pad = (-n) % chunk
    Zp = jnp.pad(Z, ((0, pad), (0, 0)))
    ids = jnp.arange(n + pad).reshape(-1, chunk)

    def rows(args):
        z, i = args
        d2 = jnp.sum(z * z, axis=1)[:, None] + sq[None, :] - 2.0 * (z @ Z.T)
        d2 = jnp.where(i[:, None] == jnp.arange(n)[None, :], jnp.inf, d2)
        return jax.lax.top_k(-d2, num)[1]

    out = jax.lax.map(rows, (Zp.reshape(-1, chunk, Z.shape[1]), ids))
    return out.reshape(-1, num)[:n].astype(jnp.int32)


def _tree_candidates(Z: np.ndarray, num: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    _, ii = cKDTree(Z).query(Z, k=num + 1, workers=-1)
    ii = ii.astype(np.int32)
    n = len(Z)
    # drop the frame itself (usually column 0; duplicates may put it elsewhere)
    own = ii == np.arange(n)[:, None]
    own[:, -1] |= ~own.any(axis=1)
    return ii[~own].reshape(n, num)


@partial(jax.jit, static_argnames=("chunk",))
def _exact_distances(F: Array, cand: Array, chunk: int) -> Array:
    """``‖F[i] − F[cand[i, c]]‖`` for every candidate, chunked over rows (O(T·C·P))."""
    n, C = cand.shape
    pad = (-n) % chunk
    Fp = jnp.pad(F, ((0, pad), (0, 0)))
    cp = jnp.pad(cand, ((0, pad), (0, 0)))

    def rows(args):
        f, c = args
        d = f[:, None, :] - F[c]
        return jnp.sqrt(jnp.sum(d * d, axis=-1))

    out = jax.lax.map(rows, (Fp.reshape(-1, chunk, F.shape[1]), cp.reshape(-1, chunk, C)))
    return out.reshape(-1, C)[:n]


@checked
def neighbourhood_graph(
    features: Float[Array, "n p"],
    k: int = 10,
    threshold: float | None = None,
    *,
    reduce_dim: int | None = 8,
    candidates: int | None = None,
    search: Literal["auto", "brute", "tree"] = "auto",
    chunk: int = 1024,
) -> NeighbourGraph:
    """Symmetric k-nearest-neighbour (optionally ε-capped) graph, never T × T.

    **Arguments:**

    - `features`: ``(T, P)`` frame features (e.g. `fxspace.distance_features`).
    - `k`: neighbours chosen by each frame (the graph is then symmetrised, so degrees are
      ``≥ k``).
    - `threshold`: ε; if given, edges longer than ε are dropped (the ε-graph, with each
      frame choosing at most its `k` nearest within ε).
    - `reduce_dim`: principal axes used to find candidates (``None``: exact search in the
      full space). Edge lengths are always exact distances in the full space.
    - `candidates`: candidates per frame in the reduced space (default ``max(3k, k+16)``).
    - `search`: ``"brute"`` (chunked GEMM + ``top_k``, accelerators), ``"tree"`` (host
      k-d tree; fast on CPUs at ≤ ~10 dimensions) or ``"auto"`` (tree on a CPU above
      20 000 frames in ≤ 10 dimensions, else brute).
    - `chunk`: rows per block in the brute-force and refinement passes.

    **Returns:** a `NeighbourGraph`; memory O(T·K).

    **Example:**

    ```python
    g = fx.neighbourhood_graph(fx.distance_features(positions), k=10)
    ```
    """
    F = np.asarray(features)
    if F.ndim != 2:
        raise FxspaceError(f"features must have shape (frames, dims), got {F.shape}")
    n, p = F.shape
    if not 1 <= k < n:
        raise FxspaceError(f"k must be in [1, n) = [1, {n}), got {k}")
    if not np.isfinite(F).all():
        raise FxspaceError("features contain NaN/inf: clean the frames first (clean_frames)")
    if search not in ("auto", "brute", "tree"):
        raise FxspaceError(f"search must be 'auto', 'brute' or 'tree', got {search!r}")
    exact = reduce_dim is None or reduce_dim >= p
    num = k if exact else min(n - 1, candidates or max(3 * k, k + 16))
    if num < k:
        raise FxspaceError(f"candidates must be >= k = {k}, got {candidates}")
    Z = F - F.mean(axis=0) if exact else (F - F.mean(axis=0)) @ _principal_axes(F, reduce_dim)
    d = Z.shape[1]
    if search == "auto":
        search = "tree" if (jax.default_backend() == "cpu" and n > 20000 and d <= 10) else "brute"
    if search == "tree":
        cand = _tree_candidates(np.ascontiguousarray(Z), num)
    else:
        cand = np.asarray(_brute_candidates(jnp.asarray(Z), num, min(chunk, n)))
    Fj = jnp.asarray(F)
    rows_per = max(8, min(chunk, 4_000_000 // max(1, num * p)))  # cache-sized blocks
    dist = np.asarray(_exact_distances(Fj, jnp.asarray(cand), min(rows_per, n)))
    if not exact:
        order = np.argsort(dist, axis=1)[:, :k]
        cand = np.take_along_axis(cand, order, axis=1)
        dist = np.take_along_axis(dist, order, axis=1)
    if threshold is not None:
        dist = np.where(dist <= threshold, dist, np.inf)
    rows = np.repeat(np.arange(n, dtype=np.int32), k)
    return _pack(rows, cand.reshape(-1), dist.reshape(-1), n, F.dtype)


def _release_pages(a) -> None:
    """Drop the pages of a memory-mapped array (``np.memmap`` or a view of one) from
    this process's resident set; they stay in the page cache and are read back on use."""
    while a is not None and not hasattr(a, "_mmap"):
        a = getattr(a, "base", None)
    mm = getattr(a, "_mmap", None)
    if mm is not None and hasattr(mm, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        mm.madvise(mmap.MADV_DONTNEED)


class KnnQuality(NamedTuple):
    """How close a k-NN graph is to the exact k nearest (`knn_quality`), on a sample.

    - `recall`: the share of each sampled frame's exact k nearest the graph holds (1.0:
      exact).
    - `distance_ratio`: the mean length of the graph's k shortest edges at a sampled
      frame over the mean distance to its exact k nearest (≥ 1; 1.0: exact). Where many
      frames are equally near (a held expression, whose frames differ by measurement
      noise alone) the recall can be low while the ratio stays near 1: the neighbours
      found are as near as the exact ones, only not the same frames.
    - `sample`: the frames measured.
    """

    recall: float
    distance_ratio: float
    sample: int


def _exact_neighbours(F, rows: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(indices, distances)`` ``(len(rows), k)`` of each row's exact k nearest (float64
    brute force, a block of frames at a time; ``F`` may be memory-mapped)."""
    n = F.shape[0]
    Q = np.asarray(F[rows], np.float64)  # float64: near-ties among the nearest are common
    qq = np.sum(Q * Q, axis=1)[:, None]
    best = np.full((len(rows), k), np.inf)
    idx = np.zeros((len(rows), k), np.int64)
    step = max(1, 2**22 // max(len(rows), 1))
    for s in range(0, n, step):
        B = np.asarray(F[s : s + step], np.float64)
        _release_pages(F)  # a memory-mapped F: its pages leave the resident set
        d = qq - 2.0 * (Q @ B.T) + np.sum(B * B, axis=1)[None]
        d[rows[:, None] == np.arange(s, s + len(B))[None]] = np.inf
        both = np.concatenate([best, d], axis=1)
        ids = np.concatenate([idx, np.broadcast_to(np.arange(s, s + len(B)), d.shape)], axis=1)
        at = np.argpartition(both, k - 1, axis=1)[:, :k]
        best, idx = np.take_along_axis(both, at, axis=1), np.take_along_axis(ids, at, axis=1)
    return idx, np.sqrt(np.maximum(best, 0.0))


@checked
def knn_quality(
    features: Float[Array, "n p"], graph: NeighbourGraph, k: int = 10, *,
    sample: int = 1000, seed: int = 0,
) -> KnnQuality:  # fmt: skip
    """`KnnQuality` (recall and distance ratio) of ``graph`` against each of ``sample``
    frames' exact ``k`` nearest neighbours (Euclidean, full feature space), drawn at
    random. The exact neighbours are found by brute force over every frame, a block of
    frames at a time (never ``T × T``; memory-mapped features stay out of memory).

    **Example:** ``q = fx.expression.knn_quality(F, g, k=10); q.recall, q.distance_ratio``"""
    F = features if isinstance(features, np.ndarray) else np.asarray(features)
    n = F.shape[0]
    if graph.num_frames != n:
        raise FxspaceError(f"graph has {graph.num_frames} frames, features {n}: build the "
                           "graph from these features")  # fmt: skip
    if not 1 <= k < n:
        raise FxspaceError(f"k must be in [1, n) = [1, {n}), got {k}")
    rows = np.random.default_rng(seed).choice(n, size=min(int(sample), n), replace=False)
    idx, dist = _exact_neighbours(F, rows, k)
    have = np.asarray(graph.indices)[rows]
    held = (idx[:, :, None] == have[:, None, :]).any(axis=2)
    w = np.sort(np.asarray(graph.weights, np.float64)[rows], axis=1)[:, :k]
    exact = dist.mean(axis=1)
    ok = exact > 0
    ratio = float(np.mean(w.mean(axis=1)[ok] / exact[ok])) if ok.any() else 1.0
    return KnnQuality(float(held.mean()), ratio, len(rows))


@checked
def knn_recall(
    features: Float[Array, "n p"], graph: NeighbourGraph, k: int = 10, *,
    sample: int = 1000, seed: int = 0,
) -> float:  # fmt: skip
    """How many of each frame's exact ``k`` nearest neighbours (Euclidean, full feature
    space) the graph holds, averaged over ``sample`` frames drawn at random: 1.0 when the
    search is exact (`knn_quality`'s `recall`; it also gives the distance ratio).

    **Example:** ``fx.expression.knn_recall(F, g, k=10)``"""
    return knn_quality(features, graph, k, sample=sample, seed=seed).recall


@checked
def sparse_components(graph: NeighbourGraph) -> tuple[int, np.ndarray]:
    """``(n_components, labels)`` of a `NeighbourGraph` (host, O(T·K))."""
    from scipy.sparse.csgraph import connected_components as cc

    n_comp, labels = cc(to_scipy(graph), directed=False)
    return int(n_comp), labels


@checked
def check_sparse_connected(graph: NeighbourGraph) -> None:
    """Raise `DisconnectedGraphError` naming the components and the fix."""
    n_comp, labels = sparse_components(graph)
    if n_comp == 1:
        return
    sizes = np.bincount(labels)
    raise DisconnectedGraphError(
        f"the neighbourhood graph has {n_comp} connected components "
        f"(sizes {sorted(sizes.tolist(), reverse=True)[:10]}): raise k or the threshold, "
        "or drop the isolated frames"
    )


@checked
def sparse_shortest_path(graph: NeighbourGraph, i: int, j: int) -> np.ndarray:
    """Frames of a shortest path from ``i`` to ``j`` inclusive on a `NeighbourGraph`.

    One single-source Dijkstra from ``i`` with predecessors (host, O(E log T), stopped once
    ``j`` is settled) — paths between frames without a ``T × T`` next-hop matrix.

    **Raises:** `DisconnectedGraphError` when ``j`` is unreachable from ``i``.
    """
    from scipy.sparse.csgraph import dijkstra

    n = graph.num_frames
    i, j = check_index(i, "i", n), check_index(j, "j", n)  # a float or NaN is refused
    if i == j:
        return np.asarray([i], dtype=np.int64)
    d, pred = dijkstra(to_scipy(graph), directed=False, indices=i, return_predecessors=True)
    if not np.isfinite(d[j]):
        raise DisconnectedGraphError(
            f"frame {j} is not reachable from frame {i}: the graph is disconnected; raise k "
            "or the threshold"
        )
    path = [j]
    while path[-1] != i:
        path.append(int(pred[path[-1]]))
    return np.asarray(path[::-1], dtype=np.int64)
