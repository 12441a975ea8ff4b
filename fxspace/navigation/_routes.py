"""Key-frame navigation through the hierarchy (Kim & Jung §4.2–4.3), at every size.

The animator picks key centres at a level (e.g. 7-3-9-1 at the first level); consecutive
picks must be linked. The frame path runs along the shortest paths between the picked
centres' frames. At the next level the centres near that path are the candidates to
re-pick from; at the finest level (every frame a centre) the route's frames are the
animation. Written once against `Level` and the frames' *paths*
(`fxspace.expression.Paths`: `Geodesics` or a `NeighbourGraph`).

All functions are pure: a `Route` in, a new `Route` out.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fxspace._validate import as_float_array, check_indices, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.navigation._level import Hierarchy, Level, _components

__all__ = [
    "NavigationError",
    "Route",
    "frame_path",
    "make_route",
    "path_candidates",
    "refine_route",
    "navigate",
    "is_graph_walk",
    "bridge_keys",
]


class NavigationError(FxspaceError):
    """A navigation request is invalid (unknown level/centre, unlinked key frames)."""


class Route(NamedTuple):
    """A navigation route at one level.

    - `level`: the level index (0 = coarsest).
    - `centres`: the key centres picked at that level, in order.
    - `key_frames`: (k,) the frames showing those centres.
    - `frames`: (L,) the frame path through them along shortest paths.
    - `anchors`: the frames the animator picked first (kept through automatic refinement,
      so at the finest level, where every frame is a centre, the route passes them).
    """

    level: int
    centres: tuple[int, ...]
    key_frames: np.ndarray
    frames: np.ndarray
    anchors: tuple[int, ...] = ()


def _hierarchy(h) -> Hierarchy:
    if not isinstance(h, Hierarchy):
        raise NavigationError(
            f"h must be a Hierarchy (build_hierarchy), got {type(h).__name__}; a list of "
            "levels is wrapped as Hierarchy(tuple(levels), embedding)"
        )
    return h


def _paths(paths):
    if not hasattr(paths, "path") or not hasattr(paths, "num_frames"):
        raise NavigationError(
            f"paths must be the frames' Geodesics or NeighbourGraph (fxspace.expression.Paths),"
            f" got {type(paths).__name__}"
        )
    return paths


def _pick(h: Hierarchy, level: int) -> Level:
    h = _hierarchy(h)
    if not isinstance(level, int | np.integer) or not 0 <= int(level) < len(h.levels):
        raise NavigationError(
            f"level must be an integer in [0, {len(h.levels) - 1}], got {level!r}"
        )
    return h.levels[int(level)]


def _level(h: Hierarchy, level: int) -> Level:
    lv = _pick(h, level)
    if lv.links is None:
        raise NavigationError(
            f"level {level} has no links: build the hierarchy with its paths (and a "
            "LinkRule whose max_centres includes this level)"
        )
    return lv


def _check_centres(lv: Level, level: int, cs: Sequence[int]) -> None:
    for c in cs:
        if not 0 <= c < lv.n_clusters:
            raise NavigationError(
                f"centre {c} does not exist at level {level} (it has {lv.n_clusters} centres)"
            )


@checked
def frame_path(paths, key_frames: Sequence[int]) -> np.ndarray:
    """Frames along shortest paths through ``key_frames`` in order (joins not repeated)."""
    if isinstance(key_frames, str | bytes) or not hasattr(key_frames, "__iter__"):
        raise NavigationError(f"key_frames must be a sequence of frame indices, got {key_frames!r}")
    kf = [int(f) for f in key_frames]
    if not kf:
        raise NavigationError("key_frames is empty: pick at least one key frame")
    out = [kf[0]]
    for a, b in zip(kf[:-1], kf[1:], strict=True):
        if a != b:
            out.extend(int(f) for f in _paths(paths).path(a, b)[1:])
    return np.asarray(out, dtype=np.int64)


def _route_frames(lv: Level, paths, cs: Sequence[int]) -> np.ndarray:
    """The frame path through the centres ``cs``: each link's path, its search bounded by
    the link's length."""
    cf = lv.center_frames
    out = [int(cf[cs[0]])]
    for a, b in zip(cs[:-1], cs[1:], strict=True):
        fa, fb = int(cf[a]), int(cf[b])
        if fa != fb:
            out.extend(int(f) for f in paths.path(fa, fb, lv.link_length(a, b))[1:])
    return np.asarray(out, np.int64)


@checked
def make_route(
    h: Hierarchy,
    paths,
    level: int,
    centres: Sequence[int],
    anchors: Sequence[int] | None = None,
) -> Route:
    """Pick key centres at ``level``; consecutive centres must be linked.

    **Arguments:** `h` a `Hierarchy`; `paths` its frames' ``Geodesics`` or
    `NeighbourGraph`; `level` (0 = coarsest); `centres` the key centres in order;
    `anchors` the animator's frames kept through refinement (default the key frames).

    **Returns:** a `Route` whose `frames` join the key frames by shortest paths. Raises
    `NavigationError` naming the first unlinked pair and the centres linked to its first
    member.
    """
    lv = _level(h, level)
    cs = [int(c) for c in centres]
    if len(cs) > 1:  # one key needs no path (nor paths)
        _paths(paths)
    if len(cs) < 1:
        raise NavigationError("centres is empty: pick at least one key centre")
    _check_centres(lv, level, cs)
    for a, b in zip(cs[:-1], cs[1:], strict=True):
        if a == b:
            raise NavigationError(f"key centre {a} is picked twice in a row at level {level}")
        if not lv.linked(a, b):
            raise NavigationError(
                f"centres {a} and {b} are not linked at level {level}: the shortest path "
                f"between them passes another centre; centres linked to {a}: "
                f"{lv.neighbours(a).tolist()}"
            )
    kf = np.asarray(lv.center_frames, np.int64)[np.asarray(cs)]
    anc = tuple(int(f) for f in (kf if anchors is None else anchors))
    return Route(int(level), tuple(cs), kf, _route_frames(lv, paths, cs), anc)


_LINK_WEIGHTS: dict = {}  # id(lengths or links) -> (weakref, (weights, directed))


def _link_weights(lv: Level):
    """``(w, directed)``: the level's links weighted by their geodesic lengths for scipy's
    Dijkstra (a stored 0 is an edge: every weight gets 1e-12; ``directed=True`` when the
    matrix is symmetric: the same distances, half the work); made once while the level
    lives."""
    import weakref

    from scipy.sparse import csr_matrix

    src = lv.lengths if lv.lengths is not None else lv.links
    key = id(src)
    hit = _LINK_WEIGHTS.get(key)
    if hit is not None and hit[0]() is src:
        return hit[1]
    w = csr_matrix(src, dtype=np.float64, copy=True)
    w.data = np.where(np.isfinite(w.data), w.data, 0.0) + 1e-12
    w.sort_indices()
    out = (w, (w != w.T).nnz == 0)
    try:
        ref = weakref.ref(src, lambda _, k=key: _LINK_WEIGHTS.pop(k, None))
    except TypeError:  # no weak references: not kept
        return out
    _LINK_WEIGHTS[key] = (ref, out)
    return out


_SMALL_SEARCH = 4096  # centres a chain search settles here before it hands over to scipy


def _near_chain(w, a: int, b: int) -> list[int] | None:
    """The shortest chain a → b by Dijkstra in Python, stopped as b is settled; ``None``
    when it settled `_SMALL_SEARCH` centres first (a far pair). Between the near centres a
    refined route asks about it settles a few dozen, where scipy's Dijkstra checks and
    allocates for the whole level on every call (~10 ms at 10⁶ centres)."""
    import heapq

    indptr, indices, data = w.indptr, w.indices, w.data
    dist, pred, done = {a: 0.0}, {a: a}, set()
    heap = [(0.0, a)]
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        if u == b:
            chain = [b]
            while chain[-1] != a:
                chain.append(pred[chain[-1]])
            return chain[::-1]
        done.add(u)
        if len(done) > _SMALL_SEARCH:
            return None
        for p in range(indptr[u], indptr[u + 1]):
            v, nd = int(indices[p]), d + float(data[p])
            if nd < dist.get(v, np.inf):
                dist[v], pred[v] = nd, u
                heapq.heappush(heap, (nd, v))
    return None


def _link_path(lv: Level, a: int, b: int) -> list[int]:
    """Shortest chain of links a → … → b (Dijkstra over the links weighted by their
    geodesic lengths): in Python for a near pair (`_near_chain`), else scipy's, bounded
    first (4 × a's longest link, doubled up to 8 times, then none; a bound that reaches b
    gives the unbounded answer: every centre on a shortest path to b lies within d(b))."""
    from scipy.sparse.csgraph import dijkstra

    w, symmetric = _link_weights(lv)
    if symmetric:
        chain = _near_chain(w, int(a), int(b))
        if chain is not None:
            return chain
    out = w.data[w.indptr[a] : w.indptr[a + 1]]
    limits = [4.0 * float(out.max()) * 2.0**t for t in range(9)] if len(out) else []
    for limit in [*limits, np.inf]:
        d, pred = dijkstra(w, directed=symmetric, indices=a, return_predecessors=True,
                           limit=limit)  # fmt: skip
        if np.isfinite(d[b]):
            break
    if not np.isfinite(d[b]):
        raise NavigationError(
            f"centre {b} cannot be reached from centre {a} through links: the ρ rule leaves "
            "them in different pieces of this level (fx.navigation.link_components); pick "
            "a centre in the same piece, or build the hierarchy with "
            "links=LinkRule(bridges=True)"
        )
    chain = [b]
    while chain[-1] != a:
        chain.append(int(pred[chain[-1]]))
    return chain[::-1]


@checked
def bridge_keys(
    h: Hierarchy, paths, level: int, keys: Sequence[int]
) -> tuple[list[int], list[str]]:
    """Make a key sequence valid at ``level``: a key repeating its predecessor is dropped;
    a pair that is not linked is joined by the shortest chain of links between them
    (Dijkstra over the level's links, weighted by their geodesic lengths). Used after
    inserting, replacing or deleting a key.

    **Returns:** ``(keys, notes)``: every consecutive pair of ``keys`` is linked; one note
    per change (e.g. ``"3 → 7 not linked: bridged via 5"``). Raises `NavigationError` for
    an unknown centre or when two keys lie in parts the links cannot join.
    """
    lv = _level(h, level)
    _paths(paths)
    ks = [int(k) for k in keys]
    _check_centres(lv, level, ks)
    if not ks:
        return [], []
    out, notes = [ks[0]], []
    for b in ks[1:]:
        a = out[-1]
        if a == b:
            notes.append(f"dropped key {b}: it repeated the key before it")
        elif lv.linked(a, b):
            out.append(b)
        else:
            chain = _link_path(lv, a, b)
            out.extend(chain[1:])
            notes.append(f"{a} → {b} not linked: bridged via {', '.join(map(str, chain[1:-1]))}")
    return out, notes


def _candidates(cpos: np.ndarray, pxy: np.ndarray, radius: float):
    """(centres within ``radius`` of the path points, their nearest path index, distance),
    ordered along the path (k-d trees: no ``(c, L)`` matrix)."""
    from scipy.spatial import cKDTree

    near = cKDTree(cpos).query_ball_point(pxy, r=radius * (1 + 1e-12) + 1e-300)
    idx = np.unique(np.concatenate([np.asarray(x, np.int64) for x in near] + [np.zeros(0, int)]))
    if len(idx) == 0:
        return idx, idx, np.zeros(0)
    d, at = cKDTree(pxy).query(cpos[idx], k=1)
    keep = d <= radius
    idx, at, d = idx[keep], at[keep].astype(np.int64), d[keep]
    order = np.lexsort((d, at))
    return idx[order], at[order], d[order]


def _radius(lv: Level, radius) -> float:
    if radius is None:
        radius = lv.radius if np.isfinite(lv.radius) else 0.0
    return check_scalar(radius, "radius", low=0.0, high=1e150)


@checked
def path_candidates(
    h: Hierarchy, level: int, frames: Sequence[int], radius: float | None = None
) -> np.ndarray:
    """Centres of ``level`` whose frame lies within ``radius`` (2-D; default the level's
    link radius ρ) of the path ``frames``, ordered along it."""
    lv = _pick(h, level)
    xy = np.asarray(h.embedding, np.float64)
    p = xy[check_indices(frames, "frames", xy.shape[0], min_len=1)]
    return _candidates(xy[lv.center_frames], p, _radius(lv, radius))[0]


def _cut_loops(seq: list[int]) -> list[int]:
    """A chain may revisit a centre; cut the loop so the route never repeats one."""
    clean: list[int] = []
    where: dict[int, int] = {}
    for k in seq:
        if k in where:
            cut = where[k] + 1
            for dropped in clean[cut:]:
                del where[dropped]
            del clean[cut:]
        else:
            where[k] = len(clean)
            clean.append(k)
    return clean


@checked
def refine_route(
    h: Hierarchy,
    paths,
    route: Route,
    picks: Sequence[int] | None = None,
    radius: float | None = None,
) -> Route:
    """Move ``route`` one level finer.

    With ``picks`` (centres of the finer level) the animator's choice is validated and
    used. Without, the refinement is automatic: the route keeps to the piece of the finer
    level's links holding most of its anchors (the rule alone may leave a level in
    pieces); each anchor maps to that piece's nearest centre, the candidates near the
    current path (`path_candidates`) are inserted in path order, any unlinked
    consecutive pair is joined by the shortest chain of links, and loops are cut.
    """
    from scipy.spatial import cKDTree

    h = _hierarchy(h)
    if not isinstance(route, Route):
        raise NavigationError(f"route must be a Route, got {type(route).__name__}")
    nxt = route.level + 1
    if nxt >= len(h.levels):
        raise NavigationError(f"route is already at the finest level ({route.level})")
    if picks is not None:
        return make_route(h, paths, nxt, picks, anchors=route.anchors or None)
    lv = _level(h, nxt)
    xy = np.asarray(h.embedding, np.float64)
    if len(xy) != _paths(paths).num_frames:
        raise NavigationError(
            f"the hierarchy's embedding has {len(xy)} frames, its paths {paths.num_frames}: "
            "pass the paths the hierarchy was built on"
        )
    cpos = xy[lv.center_frames]
    frames = np.asarray(route.frames, np.int64)
    pxy = xy[frames]
    anchor_frames = route.anchors or tuple(int(f) for f in route.key_frames)
    piece = _components(lv.links)
    near = cKDTree(cpos).query(xy[np.asarray(anchor_frames, np.int64)], k=1)[1]
    sizes = np.bincount(piece)
    main = max(set(piece[near].tolist()), key=lambda p: (int(np.sum(piece[near] == p)), sizes[p]))
    inside = np.flatnonzero(piece == main)
    tree = cKDTree(cpos[inside])
    anchors = []
    last = 0
    for kf in anchor_frames:
        k = int(inside[tree.query(xy[int(kf)], k=1)[1]])
        # position along the path: the nearest path frame at or after the previous anchor's
        last = last + int(np.argmin(np.sum((pxy[last:] - xy[int(kf)]) ** 2, axis=1)))
        anchors.append((last, 0.0, k))
    cands, at, dist = _candidates(cpos, pxy, _radius(lv, radius))
    lo, hi = anchors[0][0], anchors[-1][0]
    # candidates between the first and the last anchor, in the anchors' piece
    ok = (at >= lo) & (at < hi) & (piece[cands] == main)
    items = anchors + [(int(p), float(d), int(k))
                       for k, p, d in zip(cands[ok], at[ok], dist[ok], strict=True)]  # fmt: skip
    # a key frame anchors its centre: drop candidates repeating an anchor elsewhere
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
        if b != a:
            rep.extend([b] if lv.linked(a, b) else _link_path(lv, a, b)[1:])
    return make_route(h, paths, nxt, _cut_loops(rep), anchors=anchor_frames)


@checked
def navigate(
    h: Hierarchy,
    paths,
    centres: Sequence[int],
    level: int = 0,
    to_level: int | None = None,
) -> list[Route]:
    """Scripted navigation: pick ``centres`` at ``level`` and refine automatically down to
    ``to_level`` (default the finest: where every frame is a centre, the last route's
    `frames` are the animation). Returns the route at every level visited, coarse to fine.

    **Example:**

    ```python
    keys, _ = fx.bridge_keys(h, es.graph, 0, [0, 4, 9])
    frames = fx.navigate(h, es.graph, keys)[-1].frames
    ```
    """
    h = _hierarchy(h)
    if isinstance(centres, str | bytes) or np.asarray(centres).dtype.kind not in "iu":
        raise NavigationError(
            f"centres must be integer centre indices, got {centres!r}; pass ints (a float "
            "such as 0.9 is never rounded)"
        )
    last = len(h.levels) - 1 if to_level is None else to_level
    if not isinstance(last, int | np.integer) or not int(level) <= int(last) < len(h.levels):
        raise NavigationError(f"to_level must be in [{level}, {len(h.levels) - 1}], got {to_level}")
    routes = [make_route(h, paths, level, centres)]
    while routes[-1].level < int(last):
        routes.append(refine_route(h, paths, routes[-1]))
    return routes


def is_graph_walk(frames: Sequence[int], graph) -> bool:
    """Whether consecutive ``frames`` are distinct neighbours in ``graph`` (a dense weight
    matrix, finite = edge; or a `NeighbourGraph`)."""
    if hasattr(graph, "indices") and hasattr(graph, "weights"):
        idx, w = np.asarray(graph.indices), np.asarray(graph.weights)
        f = check_indices(frames, "frames", idx.shape[0])
        if len(f) < 2:
            return True
        hit = (idx[f[:-1]] == f[1:, None]) & np.isfinite(w[f[:-1]])
        return bool(np.all(f[1:] != f[:-1]) and np.all(hit.any(axis=1)))
    W = as_float_array(graph, "graph", ndim=2, finite="allow", xp="numpy")
    if W.shape[0] != W.shape[1]:
        raise FxspaceError(f"graph must be a square (n, n) weight matrix, got shape {W.shape}")
    f = check_indices(frames, "frames", W.shape[0])
    if len(f) < 2:
        return True
    return bool(np.all(f[1:] != f[:-1]) and np.all(np.isfinite(W[f[:-1], f[1:]])))
