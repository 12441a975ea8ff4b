"""Key-frame navigation through the hierarchy (seed paper §4–5).

The animator picks key centres at a level (e.g. 7-3-9-1 at the first level); consecutive
picks must be linked (see `fxspace.center_links`). The frame path runs along the
geodesic (frame-graph) shortest paths between the picked centres' frames. At the next
level the centres near that path are the candidates to re-pick from; at the finest
level (every frame a centre) the route's frames are the animation.

All functions are pure: a `Route` in, a new `Route` out.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from fxspace._validate import as_float_array, check_indices, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.expression import shortest_path
from fxspace.navigation._hierarchy import Hierarchy, Level
from fxspace.navigation._links import _components

if TYPE_CHECKING:
    pass

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
    - `frames`: (L,) the frame path through them along geodesic shortest paths.
    - `anchors`: the frames the animator picked first (kept through automatic refinement,
      so at the finest level, where every frame is a centre, the route passes them).
    """

    level: int
    centres: tuple[int, ...]
    key_frames: np.ndarray
    frames: np.ndarray
    anchors: tuple[int, ...] = ()


def _level(h: Hierarchy, level: int) -> Level:
    if not isinstance(level, int | np.integer) or not 0 <= int(level) < len(h.levels):
        raise NavigationError(
            f"level must be an integer in [0, {len(h.levels) - 1}], got {level!r}"
        )
    lv = h.levels[int(level)]
    if lv.links is None:
        raise NavigationError(
            f"level {level} has no links: build the hierarchy with geodesics (and a "
            "max_link_centres that includes this level)"
        )
    return lv


@checked
def frame_path(geodesics, key_frames: Sequence[int]) -> np.ndarray:
    """Concatenated geodesic shortest paths through ``key_frames`` (joins not repeated)."""
    if isinstance(key_frames, str | bytes) or not hasattr(key_frames, "__iter__"):
        raise NavigationError(f"key_frames must be a sequence of frame indices, got {key_frames!r}")
    kf = [int(f) for f in key_frames]
    if not kf:
        raise NavigationError("key_frames is empty: pick at least one key frame")
    out = [kf[0]]
    for a, b in zip(kf[:-1], kf[1:], strict=True):
        if a == b:
            continue
        if not hasattr(geodesics, "next_hop"):  # one key needs no path (nor geodesics)
            raise NavigationError(
                f"geodesics must be the frame graph's Geodesics (with next_hop), got "
                f"{type(geodesics).__name__}"
            )
        out.extend(int(f) for f in shortest_path(geodesics, a, b)[1:])
    return np.asarray(out, dtype=np.int64)


@checked
def make_route(
    h: Hierarchy,
    geodesics,
    level: int,
    centres: Sequence[int],
    anchors: Sequence[int] | None = None,
) -> Route:
    """Pick key centres at ``level``; consecutive centres must be linked.

    Raises `NavigationError` naming the first unlinked pair and the centres that
    *are* linked to its first member.
    """
    lv = _level(h, level)
    cs = [int(c) for c in centres]
    if len(cs) < 1:
        raise NavigationError("centres is empty: pick at least one key centre")
    for c in cs:
        if not 0 <= c < lv.n_clusters:
            raise NavigationError(
                f"centre {c} does not exist at level {level} (it has {lv.n_clusters} centres)"
            )
    for a, b in zip(cs[:-1], cs[1:], strict=True):
        if a == b:
            raise NavigationError(f"key centre {a} is picked twice in a row at level {level}")
        if not lv.links[a, b]:
            raise NavigationError(
                f"centres {a} and {b} are not linked at level {level}: the geodesic path "
                f"between them passes another centre; centres linked to {a}: "
                f"{lv.neighbours(a).tolist()}"
            )
    kf = lv.center_frames[np.asarray(cs)].astype(np.int64)
    anc = tuple(int(f) for f in (kf if anchors is None else anchors))
    return Route(int(level), tuple(cs), kf, frame_path(geodesics, kf), anc)


@checked
def path_candidates(
    h: Hierarchy, level: int, frames: Sequence[int], radius: float | None = None
) -> np.ndarray:
    """Centres of ``level`` whose frame lies within ``radius`` (2-D; default the level's
    link radius ρ, at least half its spacing) of the path ``frames``, ordered along it."""
    lv = h.levels[int(level)]
    xy = h.embedding
    if radius is None:
        radius = lv.radius if np.isfinite(lv.radius) else 0.0
    radius = check_scalar(radius, "radius", low=0.0, high=1e150)
    p = xy[check_indices(frames, "frames", xy.shape[0], min_len=1)]
    c = xy[lv.center_frames]
    d2 = np.sum((c[:, None, :] - p[None, :, :]) ** 2, axis=-1)  # (c, L)
    near = np.min(d2, axis=1) <= float(radius) ** 2
    idx = np.flatnonzero(near)
    order = np.lexsort((np.min(d2[idx], axis=1), np.argmin(d2[idx], axis=1)))
    return idx[order]


def _link_path(lv: Level, geodesics, a: int, b: int) -> list[int]:
    """Shortest chain of links a → … → b (Dijkstra, weights = geodesic distance)."""
    D = np.asarray(geodesics.distances)
    cf = lv.center_frames
    dist = {a: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, a)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == b:
            break
        if d > dist.get(u, np.inf):
            continue
        for v in np.flatnonzero(lv.links[u]):
            v = int(v)
            nd = d + float(D[cf[u], cf[v]])
            if nd < dist.get(v, np.inf):
                dist[v] = nd
                prev[v] = u
                heapq.heappush(heap, (nd, v))
    if b not in dist:
        raise NavigationError(
            f"centre {b} cannot be reached from centre {a} through links: the ρ rule leaves "
            "them in different pieces of this level (fx.navigation.link_components); pick "
            "a centre in the same piece, or build the hierarchy with bridges=True"
        )
    chain = [b]
    while chain[-1] != a:
        chain.append(prev[chain[-1]])
    return chain[::-1]


def _repair(lv: Level, geodesics, seq: list[int]) -> list[int]:
    out = [seq[0]]
    for b in seq[1:]:
        a = out[-1]
        if b == a:
            continue
        if lv.links[a, b]:
            out.append(b)
        else:
            out.extend(_link_path(lv, geodesics, a, b)[1:])
    return out


@checked
def bridge_keys(
    h: Hierarchy, geodesics, level: int, keys: Sequence[int]
) -> tuple[list[int], list[str]]:
    """Make a key sequence valid at ``level``: a key repeating its predecessor is dropped;
    a pair that is not linked is joined by the shortest chain of links between them
    (Dijkstra over the level's links, weighted by geodesic distance — the route then runs
    along geodesics through the bridging centres). Used after inserting, replacing or
    deleting a key.

    **Returns:** ``(keys, notes)``: every consecutive pair of ``keys`` is linked; one note
    per change (e.g. ``"3 → 7 not linked: bridged via 5"``). Raises `NavigationError` for
    an unknown centre or when two keys lie in parts the links cannot join.
    """
    lv = _level(h, level)
    ks = [int(k) for k in keys]
    for k in ks:
        if not 0 <= k < lv.n_clusters:
            raise NavigationError(
                f"centre {k} does not exist at level {level} (it has {lv.n_clusters} centres)"
            )
    if not ks:
        return [], []
    out, notes = [ks[0]], []
    for b in ks[1:]:
        a = out[-1]
        if a == b:
            notes.append(f"dropped key {b}: it repeated the key before it")
        elif lv.links[a, b]:
            out.append(b)
        else:
            chain = _link_path(lv, geodesics, a, b)
            out.extend(chain[1:])
            notes.append(f"{a} → {b} not linked: bridged via {', '.join(map(str, chain[1:-1]))}")
    return out, notes


@checked
def refine_route(
    h: Hierarchy,
    geodesics,
    route: Route,
    picks: Sequence[int] | None = None,
    radius: float | None = None,
) -> Route:
    """Move ``route`` one level finer on a dense hierarchy: the implementation behind
    `fxspace.navigation.refine_route` (`._front`, which documents the picks and the
    automatic refinement)."""
    nxt = route.level + 1
    if nxt >= len(h.levels):
        raise NavigationError(f"route is already at the finest level ({route.level})")
    if picks is not None:
        return make_route(h, geodesics, nxt, picks, anchors=route.anchors or None)
    lv = _level(h, nxt)
    xy = h.embedding
    cpos = xy[lv.center_frames]
    frames = np.asarray(route.frames)
    pxy = xy[frames]
    anchor_frames = route.anchors or tuple(int(f) for f in route.key_frames)
    # the route stays in one piece of the level's links (the paper's rule can leave
    # centres no route reaches): the piece holding most of the anchors' nearest centres
    piece = _components(lv.links)
    near = [int(np.argmin(np.sum((cpos - xy[int(kf)]) ** 2, axis=1))) for kf in anchor_frames]
    sizes = np.bincount(piece)
    main = max(set(piece[near].tolist()), key=lambda p: (int(np.sum(piece[near] == p)), sizes[p]))
    inside = piece == main
    anchors = []
    last = 0
    for kf in anchor_frames:
        d2k = np.where(inside, np.sum((cpos - xy[int(kf)]) ** 2, axis=1), np.inf)
        k = int(np.argmin(d2k))
        # position along the path: the nearest path frame at or after the previous anchor's
        d = np.sum((pxy[last:] - xy[int(kf)]) ** 2, axis=1)
        last = last + int(np.argmin(d))
        anchors.append((last, 0.0, k))
    cands = path_candidates(h, nxt, frames, radius)
    cands = cands[inside[cands]]
    d2 = np.sum((cpos[cands][:, None, :] - xy[frames][None, :, :]) ** 2, axis=-1)
    lo, hi = anchors[0][0], anchors[-1][0]
    # candidates between the first and the last anchor: the route spans anchor to anchor
    items = anchors + [
        (int(np.argmin(r)), float(np.min(r)), int(k))
        for k, r in zip(cands, d2, strict=True)
        if lo <= int(np.argmin(r)) < hi
    ]
    # a key frame anchors its centre: drop candidates repeating an anchor elsewhere
    anchor_ids = {k for _, _, k in anchors}
    items = [it for it in items if it[1] == 0.0 or it[2] not in anchor_ids]
    items.sort(key=lambda it: (it[0], it[1]))
    seq: list[int] = []
    for _, _, k in items:
        if not seq or seq[-1] != k:
            seq.append(k)
    seq = _repair(lv, geodesics, seq)
    # a chain may revisit a centre; cut the loop so the route never repeats a centre
    clean: list[int] = []
    for k in seq:
        if k in clean:
            del clean[clean.index(k) + 1 :]
        else:
            clean.append(k)
    return make_route(h, geodesics, nxt, clean, anchors=anchor_frames)


@checked
def navigate(
    h: Hierarchy,
    geodesics,
    centres: Sequence[int],
    level: int = 0,
    to_level: int | None = None,
) -> list[Route]:
    """Scripted navigation: pick ``centres`` at ``level`` and refine automatically down to
    ``to_level`` (default the finest). Returns the route at every level visited."""
    if isinstance(centres, str | bytes) or np.asarray(centres).dtype.kind not in "iu":
        raise NavigationError(
            f"centres must be integer centre indices, got {centres!r}; pass ints (a float "
            "such as 0.9 is never rounded)"
        )
    last = len(h.levels) - 1 if to_level is None else int(to_level)
    if not level <= last < len(h.levels):
        raise NavigationError(f"to_level must be in [{level}, {len(h.levels) - 1}], got {to_level}")
    routes = [make_route(h, geodesics, level, centres)]
    while routes[-1].level < last:
        routes.append(refine_route(h, geodesics, routes[-1]))
    return routes


def is_graph_walk(frames: Sequence[int], graph) -> bool:
    """Whether consecutive ``frames`` are distinct neighbours in ``graph`` (finite weight)."""
    W = as_float_array(graph, "graph", ndim=2, finite="allow", xp="numpy")
    if W.shape[0] != W.shape[1]:
        raise FxspaceError(f"graph must be a square (n, n) weight matrix, got shape {W.shape}")
    f = check_indices(frames, "frames", W.shape[0])
    if len(f) < 2:
        return True
    return bool(np.all(f[1:] != f[:-1]) and np.all(np.isfinite(W[f[:-1], f[1:]])))
