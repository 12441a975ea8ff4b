"""Hierarchy, links and routes at scale: no ``T × T`` or ``c × c`` matrix (seed paper §4
past 10⁴ frames).

The dense navigation (`fxspace.build_hierarchy`, `fxspace.make_route`) walks a
``T × T`` next-hop matrix and ``(c, c)`` link matrices. Here the same steps run on the
sparse `fxspace.expression.NeighbourGraph`:

- **levels**: fuzzy c-means with sparse memberships
  (`fxspace.cluster.fuzzy_cmeans` with ``nearest``) at c0·2^l centres; each centre is shown
  as its nearest frame; optionally a **finest level** where every frame is a centre;
- **links**: centres i—j are linked when the shortest graph path between their frames
  passes no frame within 2-D distance ρ of any other centre (the seed's rule), tested
  for each centre's `near` nearest centres in 2-D, with a *bounded* Dijkstra (with
  predecessors) per batch of centres, stopped just past the farthest candidate;
  link components left apart are bridged by their geodesically nearest centres (a
  multi-source Dijkstra from the smallest component), as in the dense hierarchy. Links,
  bridges and the links' geodesic lengths are ``scipy.sparse.csr_array``\\ s;
- **finest level** (`frame_links`): with every frame a centre, a path with an interior
  frame always passes another centre, so a link is a graph edge that is itself a
  shortest path and whose ends have no other frame within ρ; the shortest-path test is a
  local search bounded by the edge's length, and the bridges are the minimum spanning
  forest of the link components (no Dijkstra over the whole graph);
- **routes**: key frames joined by shortest graph paths
  (`fxspace.shortest_path` on the graph); routes refined level by level in
  `fxspace.navigate` on the graph.

Memory O(T·(K + B)) for a batch of B centres' Dijkstra rows; the finest level O(T·K).
This is the sparse implementation behind `fxspace.build_hierarchy`, `center_links`,
`frame_path` and `hierarchy_to_arrays` (`._front`) when they are given a `NeighbourGraph`.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.cluster import SparseFCMResult, fuzzy_cmeans
from fxspace.errors import FxspaceError
from fxspace.expression import NeighbourGraph, dijkstra_csr, shortest_path

__all__ = [
    "SparseLevel",
    "sparse_levels",
    "sparse_links",
    "frame_links",
    "finest_level",
    "sparse_hierarchy",
    "sparse_route",
    "sparse_levels_to_arrays",
    "sparse_levels_from_arrays",
]


class SparseLevel(NamedTuple):
    """One level of the hierarchy at scale.

    - `n_clusters`: c; `centers`: ``(c, 2)``; `center_frames`: ``(c,)`` nearest frames.
    - `links`, `bridges`: ``(c, c)`` symmetric ``scipy.sparse.csr_array`` of bool with
      sorted indices and no stored diagonal (bridges ⊂ links); ``links[i, j]`` reads one
      pair, ``links.indices[links.indptr[i]:links.indptr[i + 1]]`` (or `neighbours`)
      the centres linked to i.
    - `fcm`: the `fxspace.cluster.SparseFCMResult` of the level; None at the finest level
      (every frame a centre: no clustering).
    - `radius`: the ρ of the links (nan when not recorded).
    - `lengths`: ``(c, c)`` ``csr_array`` of float64 with the sparsity of `links`: the
      geodesic (graph) distance between the frames of each linked pair (None when not
      recorded). Navigation weighs link chains by it.
    """

    n_clusters: int
    centers: np.ndarray
    center_frames: np.ndarray
    links: object
    bridges: object
    fcm: SparseFCMResult | None
    radius: float = float("nan")
    lengths: object = None

    def neighbours(self, k: int) -> np.ndarray:
        """Centres linked to centre ``k`` (ascending)."""
        lk = self.links
        return np.asarray(lk.indices[lk.indptr[k] : lk.indptr[k + 1]], np.int64)


def _nearest_frames(Y: np.ndarray, centers: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return cKDTree(Y).query(centers, k=1)[1].astype(np.int64)


def _default_rho(tree, pos: np.ndarray) -> float:
    """Half the median (nonzero) nearest-centre spacing in 2-D."""
    if len(pos) < 2:
        return 0.0
    nn = tree.query(pos, k=2)[0][:, 1]
    return 0.5 * float(np.median(nn[nn > 0])) if np.any(nn > 0) else 0.0


def _pair_csr(i: np.ndarray, j: np.ndarray, vals: np.ndarray, c: int):
    """Symmetric ``csr_array`` from unique unordered pairs (i ≠ j) and their values."""
    from scipy.sparse import csr_array

    i = np.asarray(i, np.int64)
    j = np.asarray(j, np.int64)
    vals = np.asarray(vals)
    m = csr_array(
        (np.concatenate([vals, vals]), (np.concatenate([i, j]), np.concatenate([j, i]))),
        shape=(c, c),
    )
    m.sum_duplicates()
    m.sort_indices()
    return m


def _level_csrs(pairs: dict, bridge_pairs: set, c: int):
    """(links, bridges, lengths) csr_arrays from ``{(i, j): length}`` (i < j)."""
    if pairs:
        ij = np.asarray(list(pairs.keys()), np.int64).reshape(-1, 2)
        ln = np.asarray(list(pairs.values()), np.float64)
    else:
        ij = np.zeros((0, 2), np.int64)
        ln = np.zeros(0)
    bij = np.asarray(sorted(bridge_pairs), np.int64).reshape(-1, 2)
    links = _pair_csr(ij[:, 0], ij[:, 1], np.ones(len(ij), bool), c)
    bridges = _pair_csr(bij[:, 0], bij[:, 1], np.ones(len(bij), bool), c)
    lengths = _pair_csr(ij[:, 0], ij[:, 1], ln, c)
    return links, bridges, lengths


def _check_inputs(graph, embedding, name="embedding") -> np.ndarray:
    if not isinstance(graph, NeighbourGraph):
        raise FxspaceError(f"graph must be a NeighbourGraph, got {type(graph).__name__}")
    Y = np.asarray(embedding, np.float64)
    if Y.ndim != 2 or Y.shape[0] != graph.num_frames:
        raise FxspaceError(
            f"{name} must be (T, d) with T = {graph.num_frames} (the graph's frames), got "
            f"shape {Y.shape}"
        )
    if not np.all(np.isfinite(Y)):
        raise FxspaceError(f"{name} has NaN/inf rows")
    return Y


def _add_bridges(pairs: dict, bridge_pairs: set, c: int, cf, csr, directed: bool,
                 known: dict) -> None:  # fmt: skip
    """Bridges, in place: while the links fall apart, the smallest link component joins
    its geodesically nearest centre (``known`` candidate distances across the cut bound
    the search; exact: the nearest outside centre is no farther)."""
    from scipy.sparse.csgraph import connected_components, dijkstra

    while True:
        links, _, _ = _level_csrs(pairs, bridge_pairs, c)
        n_comp, lab = connected_components(links, directed=False)
        if n_comp == 1:
            break
        inside = lab == int(np.argmin(np.bincount(lab)))
        src = np.unique(cf[inside])
        # a known candidate distance across the cut bounds the search (exact: the nearest
        # outside centre is no farther)
        ub = min((v for (p, q), v in known.items() if inside[p] != inside[q]), default=np.inf)
        d, _, sources = dijkstra(
            csr,
            directed=directed,
            indices=src,
            min_only=True,
            return_predecessors=True,
            limit=ub * (1 + 1e-9) + 1e-12,
        )
        outside = np.flatnonzero(~inside)
        dout = d[cf[outside]]
        if not np.isfinite(dout).any():
            break  # the frame graph itself is disconnected
        m = float(dout.min())
        first_in = {}  # frame → lowest inside centre showing it
        for k in np.flatnonzero(inside)[::-1]:
            first_in[int(cf[k])] = int(k)
        i, j = min((first_in[int(sources[cf[b]])], int(b)) for b in outside[dout == m])
        key = (min(i, j), max(i, j))
        pairs[key] = m
        bridge_pairs.add(key)


def _sparse_links(graph, embedding, center_frames, rho=None, near=6, batch=64):
    """`sparse_links` plus the links' geodesic lengths and the ρ used."""
    from scipy.sparse.csgraph import connected_components, dijkstra
    from scipy.spatial import cKDTree

    Y = _check_inputs(graph, embedding)
    cf = np.asarray(center_frames, np.int64).reshape(-1)
    if cf.size and not (0 <= cf.min() and cf.max() < len(Y)):
        raise FxspaceError(f"center_frames must index the {len(Y)} frames")
    if int(near) < 1:
        raise FxspaceError(f"near must be >= 1, got {near}")
    if int(batch) < 1:
        raise FxspaceError(f"batch must be >= 1, got {batch}")
    c = len(cf)
    pairs: dict[tuple[int, int], float] = {}
    bridge_pairs: set[tuple[int, int]] = set()
    if c < 2:
        return (*_level_csrs(pairs, bridge_pairs, c), 0.0 if rho is None else float(rho))
    pos = Y[cf]
    tree = cKDTree(pos)
    if rho is None:
        rho = _default_rho(tree, pos)
    rho = float(rho)
    kq = min(int(near) + 1, c)
    cand = tree.query(pos, k=kq)[1][:, 1:]
    csr, directed = dijkstra_csr(graph)  # symmetric: directed=True, half the work
    _, glab = connected_components(csr, directed=False)
    reach = glab[cf][:, None] == glab[cf[cand]]  # a candidate in another part: never linked
    e2 = np.linalg.norm(pos[:, None, :] - pos[cand], axis=-1)  # 2-D candidate distances
    ratio = None  # running max of geodesic / 2-D distance over the candidates seen
    known: dict[tuple[int, int], float] = {}  # geodesic distances of candidate pairs

    def test(r, i, d, pred):
        for j in cand[i]:
            a, b = min(i, j), max(i, j)
            if i == j or not np.isfinite(d[r, cf[j]]):
                continue
            known[(int(a), int(b))] = float(d[r, cf[j]])  # bounds the bridges' search
            if (a, b) in pairs:
                continue
            path = [cf[j]]
            while path[-1] != cf[i]:
                path.append(pred[r, path[-1]])
            dist, idx = tree.query(Y[path], k=min(3, c), distance_upper_bound=rho)
            other = np.isfinite(dist) & (idx != i) & (idx != j) & (idx < c)
            other &= cf[np.minimum(idx, c - 1)] != cf[i]
            other &= cf[np.minimum(idx, c - 1)] != cf[j]
            if not other.any():
                pairs[(int(a), int(b))] = float(d[r, cf[j]])

    for s in range(0, c, int(batch)):
        pending = np.arange(s, min(s + int(batch), c))
        limit = np.inf
        if ratio is not None:
            far = np.max(np.where(reach[pending], e2[pending], 0.0))
            limit = ratio * far * 1.25 if far > 0 else np.inf
        while len(pending):
            d, pred = dijkstra(
                csr, directed=directed, indices=cf[pending], return_predecessors=True, limit=limit
            )
            got = np.isfinite(d[np.arange(len(pending))[:, None], cf[cand[pending]]])
            done = np.all(got | ~reach[pending], axis=1)
            for r in np.flatnonzero(done):
                test(r, int(pending[r]), d, pred)
            ok = got & reach[pending] & (e2[pending] > 0)
            if ok.any():
                rr = d[np.arange(len(pending))[:, None], cf[cand[pending]]][ok] / e2[pending][ok]
                ratio = max(ratio or 0.0, float(rr.max()))
            pending = pending[~done]
            limit = limit * 2.0 if np.isfinite(limit) and limit > 0 else np.inf
    _add_bridges(pairs, bridge_pairs, c, cf, csr, directed, known)
    return (*_level_csrs(pairs, bridge_pairs, c), rho)


def sparse_links(
    graph: NeighbourGraph,
    embedding: Float[Array, "T 2"],
    center_frames: np.ndarray,
    rho: float | None = None,
    near: int = 6,
    batch: int = 64,
) -> tuple[object, object]:
    """Links between centres on the sparse graph (seed §4 rule, see the module docstring).

    No ``(c, c)`` dense array: each batch of centres runs one Dijkstra bounded just past
    its farthest candidate (the bound is learned from the geodesic / 2-D ratio of the
    candidates seen and doubled for a centre whose candidates it misses); bridges come
    from a multi-source Dijkstra from the smallest link component.

    **Arguments:** `graph`; `embedding` ``(T, 2)``; `center_frames` ``(c,)``; `rho` (default
    half the median nearest-centre spacing); `near` candidate neighbours per centre;
    `batch` centres per Dijkstra call (memory ``batch × T``).

    **Returns:** ``(links, bridges)``, ``(c, c)`` symmetric ``scipy.sparse.csr_array`` of
    bool, no diagonal.

    **Example:**

    ```python
    links, bridges = fx.navigation.sparse_links(es.graph, es.embedding, frames)
    linked_to_0 = links.indices[links.indptr[0] : links.indptr[1]]
    ```
    """
    links, bridges, _, _ = _sparse_links(graph, embedding, center_frames, rho, near, batch)
    return links, bridges


def _edge_weights(idx: np.ndarray, w: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Weight of graph edge i—j for each pair (inf where there is none)."""
    out = np.full(len(i), np.inf)
    for s in range(0, len(i), 65536):
        sl = slice(s, s + 65536)
        hit = idx[i[sl]] == j[sl, None]
        ww = np.where(hit, w[i[sl]], np.inf)
        out[sl] = ww.min(axis=1)
    return out


def _edges_are_shortest(
    idx: np.ndarray, w: np.ndarray, pi: np.ndarray, pj: np.ndarray, pw: np.ndarray, chunk: int
) -> np.ndarray:
    """For each edge pi—pj of length pw: True when no other path is strictly shorter.

    A Dijkstra-like search from pi per edge, vectorised over the edges, bounded by pw (it
    only visits frames nearer than pw): O(edges · ball · K)."""
    T = idx.shape[0]
    step = max(1024, (1 << 21) // max(idx.shape[1], 1))
    ok = np.ones(len(pi), bool)
    for s in range(0, len(pi), chunk):
        src, dst, bound = pi[s : s + chunk], pj[s : s + chunk], pw[s : s + chunk]
        n = len(src)
        blocked = np.zeros(n, bool)
        fp = np.arange(n)
        fn = src.copy()
        fd = np.zeros(n)
        best_k = fp * T + fn
        best_d = fd.copy()
        while len(fp):
            parts = []
            for s2 in range(0, len(fp), step):  # ≤ step × K candidates in memory at once
                qp, qn, qd = fp[s2 : s2 + step], fn[s2 : s2 + step], fd[s2 : s2 + step]
                nb = idx[qn]
                nd = qd[:, None] + w[qn]
                keep = nd < bound[qp][:, None]
                keep &= nb != src[qp][:, None]
                keep &= ~((qn == src[qp])[:, None] & (nb == dst[qp][:, None]))  # the edge
                r, col = np.nonzero(keep)
                parts.append((qp[r], nb[r, col], nd[r, col]))
            p = np.concatenate([x[0] for x in parts])
            node = np.concatenate([x[1] for x in parts])
            dd = np.concatenate([x[2] for x in parts])
            hit = node == dst[p]
            blocked[p[hit]] = True
            live = ~blocked[p]
            p, node, dd = p[live], node[live], dd[live]
            key = p.astype(np.int64) * T + node
            order = np.lexsort((dd, key))
            key, dd, p, node = key[order], dd[order], p[order], node[order]
            first = np.ones(len(key), bool)
            first[1:] = key[1:] != key[:-1]
            key, dd, p, node = key[first], dd[first], p[first], node[first]
            at = np.searchsorted(best_k, key)
            atc = np.minimum(at, len(best_k) - 1)
            seen = (at < len(best_k)) & (best_k[atc] == key)
            better = ~seen | (dd < best_d[atc])
            key, dd, p, node = key[better], dd[better], p[better], node[better]
            # record the improvements (replace or insert)
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


def _forest_bridges(lab, n_comp, eu, ev, ew, sizes, minnode):
    """Bridges of link components ``lab`` as the dense rule adds them (the smallest
    component, ties to the lowest frame, joins its nearest other component; stop when the
    smallest cannot reach another): at every step that is the lightest frame-graph edge
    leaving it, an edge of the minimum spanning forest of the components."""
    from scipy.sparse import csr_array
    from scipy.sparse.csgraph import minimum_spanning_tree

    la, lb = lab[eu], lab[ev]
    cross = la != lb
    eu, ev, ew, la, lb = eu[cross], ev[cross], ew[cross], la[cross], lb[cross]
    lo, hi = np.minimum(la, lb), np.maximum(la, lb)
    order = np.lexsort((ew, hi, lo))
    eu, ev, ew, lo, hi = eu[order], ev[order], ew[order], lo[order], hi[order]
    first = np.ones(len(lo), bool)
    first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    eu, ev, ew, lo, hi = eu[first], ev[first], ew[first], lo[first], hi[first]
    rank = np.empty(len(ew))
    rank[np.argsort(ew, kind="stable")] = np.arange(1, len(ew) + 1)
    q = csr_array((rank, (lo, hi)), shape=(n_comp, n_comp))
    mst = minimum_spanning_tree(q).tocoo()
    eid = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(lo, hi, strict=True))}
    heaps: dict[int, list] = {k: [] for k in range(n_comp)}
    for a, b in zip(mst.row, mst.col, strict=True):
        a, b = int(min(a, b)), int(max(a, b))
        k = eid[(a, b)]
        heapq.heappush(heaps[a], (rank[k], k))
        heapq.heappush(heaps[b], (rank[k], k))
    parent = list(range(n_comp))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    size = [int(s) for s in sizes]
    mn = [int(m) for m in minnode]
    queue = [(size[k], mn[k], k) for k in range(n_comp)]
    heapq.heapify(queue)
    roots, out = n_comp, []
    while roots > 1:
        s, m, k = heapq.heappop(queue)
        if find(k) != k or size[k] != s or mn[k] != m:
            continue  # a stale entry
        h = heaps[k]
        while h and find(int(lo[h[0][1]])) == find(int(hi[h[0][1]])):
            heapq.heappop(h)
        if not h:
            break  # the frame graph itself is disconnected
        e = heapq.heappop(h)[1]
        out.append(e)
        a, b = find(int(lo[e])), find(int(hi[e]))
        if len(heaps[a]) < len(heaps[b]):
            a, b = b, a
        for item in heaps[b]:
            heapq.heappush(heaps[a], item)
        heaps[b] = []
        parent[b] = a
        size[a] += size[b]
        mn[a] = min(mn[a], mn[b])
        roots -= 1
        heapq.heappush(queue, (size[a], mn[a], a))
    out = np.asarray(out, np.int64)
    return eu[out], ev[out], ew[out]


def _frame_links(graph, embedding, rho=None, near=6, chunk=8192):
    """`frame_links` plus lengths and ρ."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    Y = _check_inputs(graph, embedding)
    if int(near) < 1:
        raise FxspaceError(f"near must be >= 1, got {near}")
    T = len(Y)
    pairs: dict = {}
    if T < 2:
        return (*_level_csrs(pairs, set(), T), 0.0 if rho is None else float(rho))
    tree = cKDTree(Y)
    if rho is None:
        rho = _default_rho(tree, Y)
    rho = float(rho)
    if not rho > 0:
        raise FxspaceError(
            f"rho must be > 0 at the finest level (every frame a centre), got {rho}: the "
            "embedding's frames coincide"
        )
    cand = tree.query(Y, k=min(int(near) + 1, T))[1][:, 1:]
    i = np.repeat(np.arange(T), cand.shape[1])
    j = cand.reshape(-1)
    a, b = np.minimum(i, j), np.maximum(i, j)
    keep = (a != b) & (b < T)
    key = np.unique(a[keep].astype(np.int64) * T + b[keep])
    a, b = key // T, key % T
    # the ends: no frame but a and b within ρ among each end's three nearest (seed rule)
    dist3, idx3 = tree.query(Y, k=min(3, T), distance_upper_bound=rho)
    dist3, idx3 = dist3.reshape(T, -1), idx3.reshape(T, -1)
    clear = np.ones(len(a), bool)
    for f in (a, b):
        other = np.isfinite(dist3[f]) & (idx3[f] != a[:, None]) & (idx3[f] != b[:, None])
        other &= idx3[f] < T
        clear &= ~other.any(axis=1)
    a, b = a[clear], b[clear]
    idx = np.asarray(graph.indices, np.int64)
    w = np.asarray(graph.weights, np.float64)
    ew = _edge_weights(idx, w, a, b)
    edge = np.isfinite(ew)
    a, b, ew = a[edge], b[edge], ew[edge]
    short = _edges_are_shortest(idx, w, a, b, ew, chunk)
    a, b, ew = a[short], b[short], ew[short]
    links = _pair_csr(a, b, np.ones(len(a), bool), T)
    n_comp, lab = connected_components(links, directed=False)
    ba = bb = np.zeros(0, np.int64)
    bw = np.zeros(0)
    if n_comp > 1:
        rows = np.repeat(np.arange(T), idx.shape[1])
        cols, ww = idx.reshape(-1), w.reshape(-1)
        up = np.isfinite(ww) & (rows < cols)
        sizes = np.bincount(lab, minlength=n_comp)
        minnode = np.full(n_comp, T, np.int64)
        np.minimum.at(minnode, lab, np.arange(T))
        ba, bb, bw = _forest_bridges(lab, n_comp, rows[up], cols[up], ww[up], sizes, minnode)
    ia = np.concatenate([a, np.minimum(ba, bb)])
    ib = np.concatenate([b, np.maximum(ba, bb)])
    lengths = _pair_csr(ia, ib, np.concatenate([ew, bw]), T)
    links = _pair_csr(ia, ib, np.ones(len(ia), bool), T)
    bridges = _pair_csr(np.minimum(ba, bb), np.maximum(ba, bb), np.ones(len(ba), bool), T)
    return links, bridges, lengths, rho


def frame_links(
    graph: NeighbourGraph,
    embedding: Float[Array, "T 2"],
    rho: float | None = None,
    near: int = 6,
) -> tuple[object, object]:
    """Links of the finest level, where every frame is a centre (seed §4 rule).

    The general rule (`sparse_links` with ``center_frames = arange(T)``) without a
    Dijkstra per frame: a shortest path with an interior frame passes that frame, itself
    a centre, so frames i—j (``j`` among the `near` nearest of ``i`` in 2-D, or the
    reverse) are linked exactly when i—j is a graph edge, the edge is a shortest path
    (no other path is strictly shorter: a search from i bounded by the edge's length) and
    neither end has another frame within ρ among its three nearest. Link components are
    then bridged by the lightest graph edges between them, in the dense rule's order
    (a minimum spanning forest of the components). Equal to `sparse_links` on the same
    input (ties between path lengths aside). Memory O(T·K).

    **Arguments:** `graph`; `embedding` ``(T, 2)``; `rho` (default half the median
    nearest-frame spacing; must be > 0); `near` candidate neighbours per frame.

    **Returns:** ``(links, bridges)``, ``(T, T)`` symmetric ``scipy.sparse.csr_array`` of
    bool, no diagonal.

    **Example:**

    ```python
    links, bridges = fx.navigation.frame_links(es.graph, es.embedding)
    ```
    """
    links, bridges, _, _ = _frame_links(graph, embedding, rho, near)
    return links, bridges


def finest_level(
    embedding: Float[Array, "T 2"],
    graph: NeighbourGraph,
    *,
    links: bool = True,
    rho: float | None = None,
    near: int = 6,
) -> SparseLevel:
    """The level where every frame is a centre (the seed's last level, c = T).

    No clustering: ``centers`` is the embedding, ``center_frames`` is ``arange(T)`` and
    ``fcm`` is None; the links come from `frame_links` (memory O(T·K)).

    **Arguments:** `embedding` ``(T, 2)``; `graph`; `links` compute the links (else
    empty); `rho` (default half the median nearest-frame spacing); `near` candidate
    neighbours per frame.

    **Returns:** a `SparseLevel` with ``n_clusters = T``.

    **Example:**

    ```python
    h = fx.navigation.sparse_hierarchy(es.embedding, es.graph, levels=5)
    h.append(fx.navigation.finest_level(es.embedding, es.graph))
    ```
    """
    from scipy.spatial import cKDTree

    Yn = _check_inputs(graph, embedding)
    T = Yn.shape[0]
    if links:
        lk, br, ln, r = _frame_links(graph, Yn, rho, near)
    else:
        lk, br, ln = _level_csrs({}, set(), T)
        r = _default_rho(cKDTree(Yn), Yn) if rho is None else float(rho)
    return SparseLevel(T, Yn.copy(), np.arange(T, dtype=np.int64), lk, br, None, r, ln)


def sparse_levels(c0: int, levels: int, n_frames: int) -> tuple[int, ...]:
    """c0, 2c0, 4c0, … (at most `levels`, each at most the number of frames)."""
    return tuple(c for c in (c0 * 2**lv for lv in range(levels)) if c <= n_frames)


@checked
def sparse_hierarchy(
    embedding: Float[Array, "T 2"],
    graph: NeighbourGraph,
    levels: int = 4,
    c0: int = 10,
    *,
    key: Array | None = None,
    nearest: int = 8,
    links: bool = True,
    finest: bool = False,
) -> list[SparseLevel]:
    """FCM levels (sparse memberships) and their links on the sparse graph.

    **Arguments:** `embedding` ``(T, 2)``; `graph` the frames' neighbourhood graph;
    `levels` levels of c0·2^l centres; `key` seeding; `nearest` memberships kept per
    frame; `links` compute the links (else empty); `finest` also append the level where
    every frame is a centre (``centers`` = the embedding, ``center_frames`` =
    ``arange(T)``, ``fcm`` = None, links by `frame_links`).

    **Returns:** a list of `SparseLevel`, coarse to fine.

    **Example:**

    ```python
    h = fx.navigation.sparse_hierarchy(es.embedding, es.graph, levels=5, finest=True)
    routes = fx.navigation.sparse_navigate(h, es.embedding, es.graph, [0, 3, 7])
    frames = routes[-1].frames  # the animation, frame by frame
    ```
    """
    from scipy.spatial import cKDTree

    Y = jax.numpy.asarray(embedding)
    Yn = np.asarray(Y, np.float64)
    key = jax.random.key(0) if key is None else key
    # every level's FCM is dispatched first (JAX runs it asynchronously), so the host's
    # link searches (scipy's Dijkstra) of one level overlap the FCM of the next
    sizes = sparse_levels(c0, levels, Y.shape[0])
    fits = [fuzzy_cmeans(Y, c, nearest=nearest, key=jax.random.fold_in(key, lv))
            for lv, c in enumerate(sizes)]  # fmt: skip
    last = finest_level(Yn, graph, links=links) if finest else None
    out = []
    for c, res in zip(sizes, fits, strict=True):
        centers = np.asarray(res.centers)
        cf = _nearest_frames(Yn, centers)
        rho = _default_rho(cKDTree(Yn[cf]), Yn[cf])
        if links:
            lk, br, ln, rho = _sparse_links(graph, Yn, cf, rho)
        else:
            lk, br, ln = _level_csrs({}, set(), c)
        out.append(SparseLevel(c, centers, cf, lk, br, res, rho, ln))
    return out if last is None else [*out, last]


@checked
def sparse_route(graph: NeighbourGraph, key_frames: Sequence[int]) -> np.ndarray:
    """Frames along shortest graph paths through the key frames in order (no repeats at
    the joins)."""
    keys = [int(k) for k in key_frames]
    if len(keys) < 1:
        raise FxspaceError("key_frames must name at least one frame")
    frames = [np.asarray(keys[:1], np.int64)]
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        frames.append(shortest_path(graph, a, b)[1:])
    return np.concatenate(frames)


def _csr_parts(m, c: int, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if m is None:
        return np.zeros(c + 1, np.int64), np.zeros(0, np.int64), np.zeros(0, dtype)
    return (np.asarray(m.indptr, np.int64), np.asarray(m.indices, np.int64),
            np.asarray(m.data, dtype))  # fmt: skip


def sparse_levels_to_arrays(levels: Sequence[SparseLevel]) -> dict[str, np.ndarray]:
    """Flat arrays of a sparse hierarchy (for ``.npz`` files and run caches): per level
    the centres, their frames, ρ and the links / bridges / lengths in CSR form. The FCM
    results are not kept (`sparse_levels_from_arrays` gives ``fcm = None``).

    **Example:**

    ```python
    np.savez("h.npz", **fx.navigation.sparse_levels_to_arrays(h))
    h2 = fx.navigation.sparse_levels_from_arrays(np.load("h.npz"))
    ```
    """
    if not isinstance(levels, Sequence) or isinstance(levels, str):
        raise FxspaceError(
            f"levels must be a list of SparseLevel (sparse_hierarchy), got {type(levels).__name__}"
        )
    out: dict[str, np.ndarray] = {"n_levels": np.asarray(len(levels), np.int64)}
    for i, lv in enumerate(levels):
        if not isinstance(lv, SparseLevel):
            raise FxspaceError(f"levels[{i}] must be a SparseLevel, got {type(lv).__name__}")
        c = int(lv.n_clusters)
        out[f"l{i}_centers"] = np.asarray(lv.centers, np.float64)
        out[f"l{i}_center_frames"] = np.asarray(lv.center_frames, np.int64)
        out[f"l{i}_radius"] = np.asarray(lv.radius, np.float64)
        out[f"l{i}_links_indptr"], out[f"l{i}_links_indices"], _ = _csr_parts(lv.links, c, bool)
        out[f"l{i}_bridges_indptr"], out[f"l{i}_bridges_indices"], _ = _csr_parts(
            lv.bridges, c, bool
        )
        has = lv.lengths is not None
        out[f"l{i}_has_lengths"] = np.asarray(has)
        out[f"l{i}_lengths"] = _csr_parts(lv.lengths, c, np.float64)[2] if has else np.zeros(0)
    return out


def sparse_levels_from_arrays(arrays) -> list[SparseLevel]:
    """The levels `sparse_levels_to_arrays` wrote (``fcm = None``; links, bridges and
    lengths as sorted symmetric ``csr_array``\\ s again)."""
    from scipy.sparse import csr_array

    if not hasattr(arrays, "keys"):
        raise FxspaceError(
            f"arrays must be a mapping (dict or np.load's NpzFile) from "
            f"sparse_levels_to_arrays, got {type(arrays).__name__}"
        )
    a = {k: np.asarray(arrays[k]) for k in arrays.keys()}
    if "n_levels" not in a:
        raise FxspaceError("not the arrays of sparse_levels_to_arrays: no 'n_levels'")
    try:
        return _levels_from(a, csr_array)
    except (KeyError, ValueError, TypeError, IndexError) as e:
        raise FxspaceError(
            f"arrays are not a complete sparse_levels_to_arrays result: {type(e).__name__}: {e}"
        ) from None


def _levels_from(a: dict, csr_array) -> list[SparseLevel]:
    out = []
    for i in range(int(a["n_levels"])):
        cf = a[f"l{i}_center_frames"].astype(np.int64)
        c = len(cf)

        def csr(name, data=None, c=c, i=i):
            ind = a[f"l{i}_{name}_indices"].astype(np.int64)
            vals = np.ones(len(ind), bool) if data is None else data
            return csr_array((vals, ind, a[f"l{i}_{name}_indptr"].astype(np.int64)), shape=(c, c))

        links = csr("links")
        lengths = csr("links", a[f"l{i}_lengths"]) if bool(a[f"l{i}_has_lengths"]) else None
        out.append(SparseLevel(c, a[f"l{i}_centers"], cf, links, csr("bridges"), None,
                               float(a[f"l{i}_radius"]), lengths))  # fmt: skip
    return out
