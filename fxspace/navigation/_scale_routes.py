"""Key-frame navigation through the sparse hierarchy (seed paper §4–5, at scale).

The same steps as `fxspace.make_route` / `fxspace.refine_route` / `fxspace.navigate`, on
the `SparseLevel`\\ s of a sparse `fxspace.build_hierarchy` and the sparse
`fxspace.expression.NeighbourGraph` instead of a ``(c, c)`` link matrix and a ``T × T``
next-hop matrix:

- consecutive key centres of a route must be linked (CSR links);
- an unlinked pair is joined by the shortest chain of links (Dijkstra over the level's
  link graph weighted by the geodesic length of each link, the level's `lengths`, as the
  dense route weighs by the geodesic distance between the centres' frames);
- a route moves one level finer by mapping its anchors to the finer level's nearest
  centres and inserting the finer centres within ρ of its frame path (k-d trees, no
  ``(c, L)`` matrix), then repairing unlinked pairs;
- the frame path joins the key frames by shortest graph paths; a linked pair's path is
  found by a Dijkstra bounded by the link's length (a direct edge as is), so the finest
  level (every frame a centre) costs no Dijkstra over the whole graph.

All functions are pure: a `Route` in, a new `Route` out. They are the sparse
implementation behind the public `fxspace.navigation` names (`._front`), which choose it
when the hierarchy's levels are `SparseLevel`\\ s and the paths a `NeighbourGraph`; the
``fx.navigation.sparse_*`` names in the examples below are these implementations.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence

import numpy as np

from fxspace.errors import DisconnectedGraphError
from fxspace.expression import NeighbourGraph, to_scipy
from fxspace.navigation._routes import NavigationError, Route
from fxspace.navigation._scale import SparseLevel

__all__ = [
    "sparse_make_route",
    "sparse_bridge_keys",
    "sparse_path_candidates",
    "sparse_refine_route",
    "sparse_navigate",
]


def _levels(levels) -> list:
    lv = list(levels) if isinstance(levels, list | tuple) else None
    if not lv or not all(isinstance(x, SparseLevel) for x in lv):
        raise NavigationError(
            "levels must be a non-empty list of SparseLevel (see sparse_hierarchy)"
        )
    return lv


def _level(levels, level: int) -> SparseLevel:
    lvs = _levels(levels)
    if not isinstance(level, int | np.integer) or not 0 <= int(level) < len(lvs):
        raise NavigationError(f"level must be an integer in [0, {len(lvs) - 1}], got {level!r}")
    lv = lvs[int(level)]
    if lv.links is None or not hasattr(lv.links, "indptr"):
        raise NavigationError(
            f"level {level} has no sparse links: build it with sparse_hierarchy(links=True)"
        )
    return lv


def _graph(graph):
    if not isinstance(graph, NeighbourGraph):
        raise NavigationError(f"graph must be a NeighbourGraph, got {type(graph).__name__}")
    csr = to_scipy(graph).astype(np.float64)
    csr.sort_indices()
    return csr


def _embedding(embedding, graph_or_n) -> np.ndarray:
    Y = np.asarray(embedding, np.float64)
    n = graph_or_n if isinstance(graph_or_n, int) else graph_or_n.num_frames
    if Y.ndim != 2 or Y.shape[0] != n:
        raise NavigationError(
            f"embedding must be (T, 2) with T = {n} (the graph's frames), got shape {Y.shape}"
        )
    return Y


def _linked(lv: SparseLevel, a: int, b: int) -> bool:
    lk = lv.links
    row = lk.indices[lk.indptr[a] : lk.indptr[a + 1]]
    k = np.searchsorted(row, b)
    return bool(k < len(row) and row[k] == b and lk.data[lk.indptr[a] + k])


def _link_length(lv: SparseLevel, a: int, b: int) -> float:
    """Geodesic length of link a—b (inf when unknown)."""
    ln = lv.lengths
    if ln is None or not hasattr(ln, "indptr"):
        return np.inf
    row = ln.indices[ln.indptr[a] : ln.indptr[a + 1]]
    k = np.searchsorted(row, b)
    return float(ln.data[ln.indptr[a] + k]) if k < len(row) and row[k] == b else np.inf


def _path(csr, a: int, b: int, bound: float) -> list[int]:
    """A shortest graph path a → b (inclusive); ``bound`` ≥ its length when known."""
    from scipy.sparse.csgraph import dijkstra

    if a == b:
        return [a]
    row = csr.indices[csr.indptr[a] : csr.indptr[a + 1]]
    k = np.searchsorted(row, b)
    if np.isfinite(bound) and k < len(row) and row[k] == b:
        if csr.data[csr.indptr[a] + k] <= bound:
            return [a, b]  # the direct edge is a shortest path
    limit = bound * (1 + 1e-9) + 1e-12 if np.isfinite(bound) else np.inf
    d, pred = dijkstra(csr, directed=False, indices=a, return_predecessors=True, limit=limit)
    if not np.isfinite(d[b]):
        if np.isfinite(limit):
            return _path(csr, a, b, np.inf)
        raise DisconnectedGraphError(f"frame {b} is not reachable from frame {a}")
    out = [b]
    while out[-1] != a:
        out.append(int(pred[out[-1]]))
    return out[::-1]


def _frame_path(lv: SparseLevel, csr, centres: Sequence[int]) -> np.ndarray:
    cf = lv.center_frames
    out = [int(cf[centres[0]])]
    for a, b in zip(centres[:-1], centres[1:], strict=True):
        fa, fb = int(cf[a]), int(cf[b])
        if fa == fb:
            continue
        out.extend(_path(csr, fa, fb, _link_length(lv, a, b))[1:])
    return np.asarray(out, np.int64)


def _check_centres(lv: SparseLevel, level: int, cs: Sequence[int]) -> None:
    for c in cs:
        if not 0 <= c < lv.n_clusters:
            raise NavigationError(
                f"centre {c} does not exist at level {level} (it has {lv.n_clusters} centres)"
            )


def sparse_make_route(
    levels: Sequence[SparseLevel],
    graph: NeighbourGraph,
    level: int,
    centres: Sequence[int],
    anchors: Sequence[int] | None = None,
) -> Route:
    """Pick key centres at ``level`` of a sparse hierarchy; consecutive centres must be
    linked (the sparse `fxspace.make_route`).

    **Arguments:** `levels` from `sparse_hierarchy`; `graph` the frames' neighbourhood
    graph; `level` the level index (0 = coarsest); `centres` the key centres in order;
    `anchors` the animator's frames to keep through refinement (default the key frames).

    **Returns:** a `Route` whose `frames` join the key frames by shortest graph paths.
    Raises `NavigationError` naming the first unlinked pair and the centres linked to its
    first member.

    **Example:**

    ```python
    h = fx.navigation.sparse_hierarchy(es.embedding, es.graph, levels=4)
    r = fx.navigation.sparse_make_route(h, es.graph, 0, [0, *h[0].neighbours(0)[:1]])
    ```
    """
    lv = _level(levels, level)
    csr = _graph(graph)
    cs = [int(c) for c in centres]
    if len(cs) < 1:
        raise NavigationError("centres is empty: pick at least one key centre")
    _check_centres(lv, level, cs)
    for a, b in zip(cs[:-1], cs[1:], strict=True):
        if a == b:
            raise NavigationError(f"key centre {a} is picked twice in a row at level {level}")
        if not _linked(lv, a, b):
            raise NavigationError(
                f"centres {a} and {b} are not linked at level {level}: the geodesic path "
                f"between them passes another centre; centres linked to {a}: "
                f"{lv.neighbours(a).tolist()}"
            )
    kf = np.asarray(lv.center_frames, np.int64)[np.asarray(cs)]
    anc = tuple(int(f) for f in (kf if anchors is None else anchors))
    return Route(int(level), tuple(cs), kf, _frame_path(lv, csr, cs), anc)


def _link_path(lv: SparseLevel, a: int, b: int) -> list[int]:
    """Shortest chain of links a → … → b (Dijkstra, weights = the links' geodesic
    lengths; 2-D distance between the centres' frames where lengths are absent)."""
    lk = lv.links
    ln = lv.lengths if lv.lengths is not None and hasattr(lv.lengths, "indptr") else None
    if ln is not None and not np.array_equal(ln.indptr, lk.indptr):
        ln = None  # not the links' sparsity: fall back to 2-D distances
    pos = np.asarray(lv.centers, np.float64)
    dist = {a: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, a)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == b:
            break
        if d > dist.get(u, np.inf):
            continue
        s, e = lk.indptr[u], lk.indptr[u + 1]
        for t in range(s, e):
            v = int(lk.indices[t])
            if ln is not None:
                w = float(ln.data[t])  # same sparsity and order as links
            else:
                w = float(np.linalg.norm(pos[u] - pos[v]))
            nd = d + w
            if nd < dist.get(v, np.inf):
                dist[v] = nd
                prev[v] = u
                heapq.heappush(heap, (nd, v))
    if b not in dist:
        raise NavigationError(f"centre {b} cannot be reached from centre {a} through links")
    chain = [b]
    while chain[-1] != a:
        chain.append(prev[chain[-1]])
    return chain[::-1]


def sparse_bridge_keys(
    levels: Sequence[SparseLevel], graph: NeighbourGraph, level: int, keys: Sequence[int]
) -> tuple[list[int], list[str]]:
    """Make a key sequence valid at ``level`` (the sparse `fxspace.bridge_keys`): a key
    repeating its predecessor is dropped; an unlinked pair is joined by the shortest chain
    of links (weighted by the links' geodesic lengths).

    **Arguments:** `levels`, `graph` as in `sparse_make_route`; `level`; `keys` centres.

    **Returns:** ``(keys, notes)``: every consecutive pair of ``keys`` is linked; one note
    per change. Raises `NavigationError` for an unknown centre or keys the links cannot
    join.

    **Example:**

    ```python
    keys, notes = fx.navigation.sparse_bridge_keys(h, es.graph, 0, [0, 5, 9])
    r = fx.navigation.sparse_make_route(h, es.graph, 0, keys)
    ```
    """
    lv = _level(levels, level)
    _graph(graph)
    ks = [int(k) for k in keys]
    _check_centres(lv, level, ks)
    if not ks:
        return [], []
    out, notes = [ks[0]], []
    for b in ks[1:]:
        a = out[-1]
        if a == b:
            notes.append(f"dropped key {b}: it repeated the key before it")
        elif _linked(lv, a, b):
            out.append(b)
        else:
            chain = _link_path(lv, a, b)
            out.extend(chain[1:])
            notes.append(f"{a} → {b} not linked: bridged via {', '.join(map(str, chain[1:-1]))}")
    return out, notes


def _radius(lv: SparseLevel, radius) -> float:
    if radius is None:
        radius = lv.radius if np.isfinite(lv.radius) else 0.0
    r = float(radius)
    if not r >= 0:
        raise NavigationError(f"radius must be >= 0, got {radius}")
    return r


def _candidates(cpos: np.ndarray, ctree, pxy: np.ndarray, radius: float):
    """(centres within ``radius`` of the path, their nearest path index, distance),
    ordered along the path."""
    from scipy.spatial import cKDTree

    near = ctree.query_ball_point(pxy, r=radius * (1 + 1e-12) + 1e-300)
    idx = np.unique(np.concatenate([np.asarray(x, np.int64) for x in near] + [np.zeros(0, int)]))
    if len(idx) == 0:
        return idx, idx, np.zeros(0)
    d, at = cKDTree(pxy).query(cpos[idx], k=1)
    keep = d <= radius
    idx, at, d = idx[keep], at[keep].astype(np.int64), d[keep]
    order = np.lexsort((d, at))
    return idx[order], at[order], d[order]


def sparse_path_candidates(
    levels: Sequence[SparseLevel],
    embedding,
    level: int,
    frames: Sequence[int],
    radius: float | None = None,
) -> np.ndarray:
    """Centres of ``level`` within ``radius`` (2-D; default the level's ρ) of the frame
    path ``frames``, ordered along it (the sparse `fxspace.path_candidates`; k-d trees,
    no ``(c, L)`` matrix).

    **Arguments:** `levels`; `embedding` ``(T, 2)``, the hierarchy's; `level`; `frames`
    the path; `radius`.

    **Returns:** ``(n,)`` centre indices.

    **Example:**

    ```python
    near = fx.navigation.sparse_path_candidates(h, es.embedding, 1, route.frames)
    ```
    """
    from scipy.spatial import cKDTree

    lv = _level(levels, level)
    Y = np.asarray(embedding, np.float64)
    f = np.asarray(frames, np.int64).reshape(-1)
    if len(f) == 0:
        raise NavigationError("frames is empty: give the path's frames")
    if Y.ndim != 2 or f.min() < 0 or f.max() >= len(Y):
        raise NavigationError(f"frames must index the embedding's {len(Y)} frames")
    cpos = Y[np.asarray(lv.center_frames, np.int64)]
    return _candidates(cpos, cKDTree(cpos), Y[f], _radius(lv, radius))[0]


def sparse_refine_route(
    levels: Sequence[SparseLevel],
    embedding,
    graph: NeighbourGraph,
    route: Route,
    picks: Sequence[int] | None = None,
    radius: float | None = None,
) -> Route:
    """Move ``route`` one level finer (the sparse `fxspace.refine_route`).

    With ``picks`` (centres of the finer level) the animator's choice is validated and
    used. Without, the refinement is automatic: each anchor maps to the finer level's
    nearest centre, the centres within ``radius`` of the current frame path are inserted
    in path order, any unlinked consecutive pair is joined by the shortest chain of links,
    and loops are cut so no centre repeats.

    **Arguments:** `levels`; `embedding` ``(T, 2)``, the hierarchy's; `graph`; `route` a
    `Route` of these levels; `picks`; `radius` (default the finer level's ρ).

    **Returns:** the `Route` at ``route.level + 1``.

    **Example:**

    ```python
    finer = fx.navigation.sparse_refine_route(h, es.embedding, es.graph, route)
    ```
    """
    from scipy.spatial import cKDTree

    lvs = _levels(levels)
    if not isinstance(route, Route):
        raise NavigationError(f"route must be a Route, got {type(route).__name__}")
    nxt = route.level + 1
    if nxt >= len(lvs):
        raise NavigationError(f"route is already at the finest level ({route.level})")
    if picks is not None:
        return sparse_make_route(lvs, graph, nxt, picks, anchors=route.anchors or None)
    lv = _level(lvs, nxt)
    xy = _embedding(embedding, graph)
    cpos = xy[np.asarray(lv.center_frames, np.int64)]
    ctree = cKDTree(cpos)
    frames = np.asarray(route.frames, np.int64)
    pxy = xy[frames]
    anchor_frames = route.anchors or tuple(int(f) for f in route.key_frames)
    anchors = []
    last = 0
    for kf in anchor_frames:
        k = int(ctree.query(xy[int(kf)], k=1)[1])
        d = np.sum((pxy[last:] - xy[int(kf)]) ** 2, axis=1)
        last = last + int(np.argmin(d))
        anchors.append((last, 0.0, k))
    cands, at, dist = _candidates(cpos, ctree, pxy, _radius(lv, radius))
    lo, hi = anchors[0][0], anchors[-1][0]
    inside = (at >= lo) & (at < hi)
    items = anchors + [
        (int(p), float(dd), int(k))
        for k, p, dd in zip(cands[inside], at[inside], dist[inside], strict=True)
    ]
    anchor_ids = {k for _, _, k in anchors}
    items = [it for it in items if it[1] == 0.0 or it[2] not in anchor_ids]
    items.sort(key=lambda it: (it[0], it[1]))
    seq: list[int] = []
    for _, _, k in items:
        if not seq or seq[-1] != k:
            seq.append(k)
    rep = [seq[0]]
    for b in seq[1:]:
        a = rep[-1]
        if b == a:
            continue
        if _linked(lv, a, b):
            rep.append(b)
        else:
            rep.extend(_link_path(lv, a, b)[1:])
    # a chain may revisit a centre; cut the loop so the route never repeats a centre
    clean: list[int] = []
    where: dict[int, int] = {}
    for k in rep:
        if k in where:
            cut = where[k] + 1
            for dropped in clean[cut:]:
                del where[dropped]
            del clean[cut:]
        else:
            where[k] = len(clean)
            clean.append(k)
    return sparse_make_route(lvs, graph, nxt, clean, anchors=anchor_frames)


def sparse_navigate(
    levels: Sequence[SparseLevel],
    embedding,
    graph: NeighbourGraph,
    centres: Sequence[int],
    level: int = 0,
    to_level: int | None = None,
) -> list[Route]:
    """Scripted navigation on a sparse hierarchy: pick ``centres`` at ``level`` and refine
    automatically down to ``to_level`` (default the finest; with
    ``sparse_hierarchy(..., finest=True)`` its route's `frames` are the animation).

    **Arguments:** `levels`; `embedding` ``(T, 2)``; `graph`; `centres` key centres at
    ``level`` (consecutive ones linked, see `sparse_bridge_keys`); `level`; `to_level`.

    **Returns:** the `Route` at every level visited, coarse to fine.

    **Example:**

    ```python
    h = fx.navigation.sparse_hierarchy(es.embedding, es.graph, levels=5, finest=True)
    keys, _ = fx.navigation.sparse_bridge_keys(h, es.graph, 0, [0, 4, 9])
    frames = fx.navigation.sparse_navigate(h, es.embedding, es.graph, keys)[-1].frames
    ```
    """
    lvs = _levels(levels)
    last = len(lvs) - 1 if to_level is None else to_level
    if not isinstance(last, int | np.integer) or not int(level) <= int(last) < len(lvs):
        raise NavigationError(f"to_level must be in [{level}, {len(lvs) - 1}], got {to_level}")
    routes = [sparse_make_route(lvs, graph, level, centres)]
    while routes[-1].level < int(last):
        routes.append(sparse_refine_route(lvs, embedding, graph, routes[-1]))
    return routes
