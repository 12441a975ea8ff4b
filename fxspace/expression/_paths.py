"""The *paths* interface of a frame graph: what navigation asks of it (Kim & Jung §4).

Two frame graphs implement it, as ott-jax's ``Geometry`` / ``PointCloud`` / ``Graph``
share one interface:

- `fxspace.expression.Geodesics` (dense: ``T × T`` distances and next hops, ~2 400
  frames) answers from its matrices;
- `fxspace.expression.NeighbourGraph` (sparse: ``T × K`` neighbours, 10⁵ frames and
  more) answers with Dijkstra searches (scipy), bounded where a bound is known.

The interface (`Paths`): `num_frames`; `path(i, j, limit)` the frames of a shortest
path (``limit``: its length, when the caller knows it — a link's; a search stops there,
and an edge that long is the path); `lengths(i, j)` the geodesic lengths of many pairs;
`toward(targets)` the shortest-path trees into some frames (distances and next hops,
``(k, T)``); `steps()` the graph's edges that are themselves shortest paths.
Navigation (`fxspace.navigation`) is written once against it.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression._row_workers import for_graph

__all__ = ["Paths"]


@runtime_checkable
class Paths(Protocol):
    """What a frame graph answers for navigation (see the module docstring)."""

    @property
    def num_frames(self) -> int: ...

    def path(self, i: int, j: int, limit: float | None = None) -> np.ndarray: ...

    def lengths(self, i, j) -> np.ndarray: ...

    def toward(self, targets) -> tuple[np.ndarray, np.ndarray]: ...

    def steps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def _pairs(i, j, n: int) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(i, np.int64).reshape(-1)
    b = np.asarray(j, np.int64).reshape(-1)
    if a.shape != b.shape:
        raise FxspaceError(f"i and j must have the same length, got {len(a)} and {len(b)}")
    for name, v in (("i", a), ("j", b)):
        if v.size and (v.min() < 0 or v.max() >= n):
            raise FxspaceError(f"{name} must index the graph's {n} frames")
    return a, b


def _targets(targets, n: int) -> np.ndarray:
    t = np.asarray(targets, np.int64).reshape(-1)
    if t.size and (t.min() < 0 or t.max() >= n):
        raise FxspaceError(f"targets must index the graph's {n} frames")
    return t


# -- dense: Geodesics ------------------------------------------------------------------


def geodesic_lengths(geo, i, j) -> np.ndarray:
    D = np.asarray(geo.distances)
    a, b = _pairs(i, j, D.shape[0])
    return D[a, b].astype(np.float64)


def geodesic_toward(geo, targets) -> tuple[np.ndarray, np.ndarray]:
    D, nh = np.asarray(geo.distances), np.asarray(geo.next_hop)
    t = _targets(targets, D.shape[0])
    return np.ascontiguousarray(D[:, t].T, np.float64), np.ascontiguousarray(nh[:, t].T, np.int32)


def geodesic_steps(geo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs i < j whose shortest path is the direct step (``next_hop[i, j] == j``)."""
    D, nh = np.asarray(geo.distances), np.asarray(geo.next_hop)
    i, j = np.nonzero(nh == np.arange(nh.shape[0])[None, :])
    keep = i < j
    i, j = i[keep].astype(np.int64), j[keep].astype(np.int64)
    return i, j, D[i, j].astype(np.float64)


# -- sparse: NeighbourGraph ------------------------------------------------------------


def _csr(graph):
    return graph.dijkstra_csr()  # the graph's own (csr, directed) for scipy's Dijkstra


def _workers(graph):
    """Worker processes holding the graph's CSR where it is large (`_row_workers`)."""
    return for_graph(graph, _csr)


def graph_toward(graph, targets, limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    from scipy.sparse.csgraph import dijkstra

    csr, directed = _csr(graph)
    t = _targets(targets, csr.shape[0])
    if not t.size:
        return np.zeros((0, csr.shape[0])), np.zeros((0, csr.shape[0]), np.int32)
    w = _workers(graph) if len(t) > 1 else None
    if w is not None:  # the same Dijkstra, the targets split between processes
        d, pred = w.rows(t, predecessors=True, limit=limit)
    else:
        d, pred = dijkstra(csr, directed=directed, indices=t, return_predecessors=True,
                           limit=limit)  # fmt: skip
    # on a symmetric graph the predecessor of f on the path from t is f's next hop to t
    hop = np.where(pred < 0, -1, pred).astype(np.int32)
    hop[np.arange(len(t)), t] = t
    return np.asarray(d, np.float64), hop


def graph_lengths(graph, i, j, batch: int = 64) -> np.ndarray:
    from scipy.sparse.csgraph import dijkstra

    csr, directed = _csr(graph)
    a, b = _pairs(i, j, csr.shape[0])
    out = np.full(len(a), np.inf)
    src, inv = np.unique(a, return_inverse=True)
    w = _workers(graph) if len(src) > 1 else None
    for s in range(0, len(src), batch):
        rows = src[s : s + batch]
        sel = (inv >= s) & (inv < s + len(rows))
        d = w.rows(rows) if w is not None else dijkstra(csr, directed=directed, indices=rows)
        out[sel] = d[inv[sel] - s, b[sel]]
    return out


def graph_path(graph, i: int, j: int, limit: float | None = None) -> np.ndarray:
    """Frames of a shortest path i → j. ``limit``: the path's length when known (a link's
    geodesic length): the search stops there (a short link costs a small ball, not the
    whole graph), and an edge i–j that long is the path, with no search at all (on the
    level where every frame is a centre each link is such an edge; a search costs ~10 ms
    on 10⁶ frames however small its ball, scipy checking the whole graph first). A
    ``limit`` the path exceeds only costs a second, unbounded search."""
    from scipy.sparse.csgraph import dijkstra

    csr, directed = _csr(graph)
    n = csr.shape[0]
    for name, v in (("i", i), ("j", j)):
        if not 0 <= int(v) < n:
            raise FxspaceError(f"{name}={v} is out of range for a graph of {n} frames")
    i, j = int(i), int(j)
    if i == j:
        return np.asarray([i], np.int64)
    lim = np.inf if limit is None or not np.isfinite(limit) else limit * (1 + 1e-9) + 1e-12
    if np.isfinite(lim):  # an edge no longer than the path's length is the path itself
        lo, hi = csr.indptr[i], csr.indptr[i + 1]
        at = lo + np.flatnonzero(csr.indices[lo:hi] == j)
        if len(at) and csr.data[at[0]] <= lim:
            return np.asarray([i, j], np.int64)
    d, pred = dijkstra(csr, directed=directed, indices=j, return_predecessors=True, limit=lim)
    if not np.isfinite(d[i]):
        if np.isfinite(lim):
            return graph_path(graph, i, j)
        raise DisconnectedGraphError(f"frame {j} is not reachable from frame {i}")
    out = [i]
    while out[-1] != j:  # the tree into j: each frame's predecessor is its next hop
        out.append(int(pred[out[-1]]))
    return np.asarray(out, np.int64)


def graph_steps(graph, chunk: int = 8192) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges i < j of the graph that are shortest paths: no other path strictly shorter.

    Path lengths are summed from i in float64 (as scipy's Dijkstra does); an exact tie
    keeps the edge. Two lower bounds settle most edges without a search (exact, not a
    heuristic): any other path leaves i by another edge and enters j by an edge from a
    third frame, so if ``least(i → ·, not j) + least(· → j, not from i)`` is not below
    the edge's length, nothing beats it (on a 10⁵-frame k = 10 graph measured, all its
    812 459 edges). The rest get a search from i bounded by the edge's length, pruned
    by the same bound on the last hop, vectorised over ``chunk`` edges
    (`_edges_are_shortest`). With a negative weight (lengths need not grow along a
    path) there is no such bound: every edge is searched, bounded by its length only.

    **Arguments:** `graph` with ``indices`` ``(T, K)`` and ``weights`` ``(T, K)``
    (``inf`` in padding slots), as `fxspace.expression.NeighbourGraph`; `chunk` the
    edges searched at once.

    **Returns:** ``(i, j, length)``: int64, int64, float64, ordered by ``(i, j)``.
    """
    idx = np.asarray(graph.indices)
    if idx.dtype not in (np.int32, np.int64):
        idx = idx.astype(np.int64)
    w = np.asarray(graph.weights)
    if w.dtype not in (np.float32, np.float64):
        w = w.astype(np.float64)
    T = idx.shape[0]
    fin = np.isfinite(w)  # the entries, row by row (NaN and padding are on no path)
    r = np.repeat(np.arange(T), fin.sum(axis=1))
    c, v = idx[fin].astype(np.int64), w[fin].astype(np.float64)
    up = r < c
    i, j, wt = r[up], c[up], v[up]
    loop = r == c
    if loop.any():  # a self-loop is never the first or last hop of another path
        r, c, v = r[~loop], c[~loop], v[~loop]
    key = i * T + j
    if key.size > 1 and not (key[1:] > key[:-1]).all():  # unsorted rows or repeats
        _, first = np.unique(key, return_index=True)
        i, j, wt = i[first], j[first], wt[first]
    if (w < 0).any():  # lengths do not grow along a path: no bound, search every edge
        ok = _edges_are_shortest(idx, w, i, j, wt, None, chunk)
        return i[ok], j[ok], wt[ok]
    lb = _last_hop_bounds(T, r, c, v, i, j)
    out = _least_other(T, r, c, v)  # least weight out of each frame, and the runner-up
    first_hop = np.where(out[1][i] == j, out[2][i], out[0][i])  # leaving i, not to j
    ok = np.ones(len(i), bool)
    s = np.flatnonzero((first_hop < wt) & (first_hop + lb < wt))
    ok[s] = _edges_are_shortest(idx, w, i[s], j[s], wt[s], lb[s], chunk)
    return i[ok], j[ok], wt[ok]


def _least_other(T: int, at, other, v) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame f: the least weight ``v`` of its entries (``at == f``), the least
    ``other`` giving it (``T`` if none), and the least weight of the entries whose
    ``other`` is not that one (``inf`` if none)."""
    m1 = np.full(T, np.inf)
    np.minimum.at(m1, at, v)
    arg1 = np.full(T, T, np.int64)
    hit = v == m1[at]
    np.minimum.at(arg1, at[hit], other[hit])
    m2 = np.full(T, np.inf)
    rest = other != arg1[at]
    np.minimum.at(m2, at[rest], v[rest])
    return m1, arg1, m2


def _last_hop_bounds(T: int, r, c, v, src, dst) -> np.ndarray:
    """A lower bound on the last hop of any path src → dst other than the direct edge
    (weights ≥ 0): the least weight into dst from a frame other than src and dst (the
    search never returns to src; it stops on reaching dst); ``inf`` where there is none.
    ``(r, c, v)``: the finite entries, self-loops left out."""
    m1, arg1, m2 = _least_other(T, c, r, v)
    return np.where(arg1[dst] == src, m2[dst], m1[dst])


class _SortedRows:
    """The graph's rows, sorted when a search first reaches them: ``idx_s``/``w_s`` each
    row's slots by weight (NaN and padding last); ``col``/``wc`` the same entries by
    frame (padding, ``T``, last; a repeated frame's least weight first), with one more
    ``T`` slot that ends a bisection."""

    def __init__(self, idx, w):
        T, K = idx.shape
        self.idx, self.w, self.done = idx, w, np.zeros(T, bool)
        self.idx_s, self.w_s = np.empty((T, K), idx.dtype), np.empty((T, K), w.dtype)
        self.col = np.empty((T, K + 1), np.int32 if T < 2**31 - 1 else np.int64)
        self.wc = np.empty((T, K + 1), w.dtype)

    def need(self, rows) -> None:
        r = np.unique(rows[~self.done[rows]])
        if not len(r):
            return
        T = self.idx.shape[0]
        o = np.argsort(self.w[r], axis=1, kind="stable")
        i_s = np.take_along_axis(self.idx[r], o, 1)
        w_s = np.take_along_axis(self.w[r], o, 1)
        ck = np.where(w_s < np.inf, i_s, T)
        o = np.argsort(ck, axis=1, kind="stable")  # by frame, then by weight
        self.idx_s[r], self.w_s[r] = i_s, w_s
        self.col[r, :-1], self.wc[r, :-1] = (
            np.take_along_axis(ck, o, 1),
            np.take_along_axis(w_s, o, 1),
        )
        self.col[r, -1], self.wc[r, -1] = T, np.inf
        self.done[r] = True


def _hop(col, wc, qn, to) -> np.ndarray:
    """The least weight of an entry qn → to (``inf`` if none): bisection along the
    rows' frames (`_SortedRows`)."""
    lo, hi = np.zeros(len(qn), np.int64), np.full(len(qn), col.shape[1] - 1)
    for _ in range(int(col.shape[1]).bit_length()):
        mid = (lo + hi) // 2
        right = col[qn, mid] < to
        lo, hi = np.where(right, mid + 1, lo), np.where(right, hi, mid)
    return np.where(col[qn, lo] == to, wc[qn, lo], np.inf)


def _expand(rows, qp, qn, qd, src, dst, bound, lb):
    """One round of the search: the frontier entries (edge qp at frame qn, length qd)
    reaching dst below the bound, and the frames worth going on from: slot by slot
    along the rows sorted by weight, an entry dropping out at its first slot where
    the length plus the last-hop bound reaches the bound (every later slot is longer)."""
    rows.need(qn)
    idx_s, w_s, col, wc = rows.idx_s, rows.w_s, rows.col, rows.wc
    # the hop to dst, looked up (it needs no room for a further hop); never the edge
    hit = (qd + _hop(col, wc, qn, dst[qp]) < bound[qp]) & (qn != src[qp])
    done = qp[hit]
    parts = []
    act = np.arange(len(qp))
    for k in range(idx_s.shape[1]):
        nd = qd[act] + w_s[qn[act], k]
        go = nd + lb[qp[act]] < bound[qp[act]]
        act, nd = act[go], nd[go]
        if not len(act):
            break
        ap, an, nb = qp[act], qn[act], idx_s[qn[act], k].astype(np.int64)
        keep = (nb != src[ap]) & ~((an == src[ap]) & (nb == dst[ap]))  # not back, not the edge
        parts.append((ap[keep], nb[keep], nd[keep]))
    return done, parts


def _edges_are_shortest(idx, w, pi, pj, pw, lb, chunk: int) -> np.ndarray:
    """Whether no path pi → pj other than the edge is strictly shorter than pw: a
    label-correcting search from pi bounded by pw, expanded by `_expand`; a frame
    other than pj is kept only when a last hop of ``lb`` could still close a shorter
    path (weights ≥ 0: the length so far, plus that hop, never exceeds a path's length
    through it); with ``lb=None``, no pruning."""
    T = idx.shape[0]
    ok = np.ones(len(pi), bool)
    if not len(pi):
        return ok
    rows = _SortedRows(idx, w)
    for s in range(0, len(pi), chunk):
        src, dst, bound = pi[s : s + chunk], pj[s : s + chunk], pw[s : s + chunk]
        low = np.zeros(len(src)) if lb is None else lb[s : s + chunk]
        n = len(src)
        blocked = np.zeros(n, bool)
        fp, fn, fd = np.arange(n), src.copy(), np.zeros(n)
        best_k, best_d = fp * T + fn, fd.copy()
        while len(fp):
            done, parts = _expand(rows, fp, fn, fd, src, dst, bound, low)
            blocked[done] = True
            parts.append((done[:0], done[:0], fd[:0]))
            p = np.concatenate([x[0] for x in parts])
            node = np.concatenate([x[1] for x in parts])
            dd = np.concatenate([x[2] for x in parts])
            blocked[p[node == dst[p]]] = True
            live = ~blocked[p]
            p, node, dd = p[live], node[live], dd[live]
            key = p.astype(np.int64) * T + node
            order = np.argsort(key, kind="stable")
            key, dd = key[order], dd[order]
            first = np.ones(len(key), bool)
            first[1:] = key[1:] != key[:-1]
            start = np.flatnonzero(first)  # each (edge, frame) once, at its least length
            dd = np.minimum.reduceat(dd, start) if len(start) else dd
            key = key[start]
            p = key // T
            node = key - p * T
            at = np.searchsorted(best_k, key)
            atc = np.minimum(at, len(best_k) - 1)
            seen = (at < len(best_k)) & (best_k[atc] == key)
            better = ~seen | (dd < best_d[atc])
            key, dd, p, node = key[better], dd[better], p[better], node[better]
            upd = seen[better]
            best_d[atc[better][upd]] = dd[upd]
            if (~upd).any():
                nk = np.concatenate([best_k, key[~upd]])
                nd_ = np.concatenate([best_d, dd[~upd]])
                o = np.argsort(nk, kind="stable")
                best_k, best_d = nk[o], nd_[o]
            fp, fn, fd = p, node, dd
        ok[s : s + chunk] = ~blocked
    return ok
