"""Links between the centres of one hierarchy level (seed paper §4).

Two centres are *linked* when the geodesic (frame-graph) path between their frames,
drawn in 2-D, passes within ρ of no other centre; ρ is a scale × the median
nearest-neighbour spacing of the level's centres, the scale found by the paper's
experiment (`link_radius_sweep`, `choose_link_scale`). A level the rule leaves in
pieces stays so unless *bridges* are asked for (the cheapest geodesic link between
pieces, outside the rule).
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import checked
from fxspace.cluster import squared_distances as _sq_dists
from fxspace.errors import FxspaceError

if TYPE_CHECKING:
    from fxspace.navigation._hierarchy import Hierarchy, Level

__all__ = [
    "EXACT_CENTRES",
    "LINK_SCALES",
    "LinkRadiusSweep",
    "center_links",
    "choose_link_scale",
    "default_link_radius",
    "link_clearance",
    "link_components",
    "link_graph_connected",
    "link_pairs",
    "link_radius_sweep",
]

LINK_SCALES = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)
"""The ρ scales `link_radius_sweep` tries by default (× each level's centre spacing)."""


@checked
def default_link_radius(points: Float[Array, "c 2"], scale: float = 0.5) -> float:
    """ρ = ``scale`` × median nearest-neighbour distance between the centres' positions
    (the level's spacing)."""
    p = np.asarray(points, dtype=np.float64)
    if scale < 0:
        raise FxspaceError(f"scale must be >= 0, got {scale}")
    if len(p) < 2:
        return 0.0
    d2 = np.sum((p[:, None, :] - p[None, :, :]) ** 2, axis=-1) if len(p) <= 512 else None
    if d2 is None:
        d2 = np.array(_sq_dists(jnp.asarray(p), jnp.asarray(p)))
    np.fill_diagonal(d2, np.inf)
    nn = np.sqrt(np.min(d2, axis=1))
    nn = nn[np.isfinite(nn) & (nn > 0)]
    return float(scale * np.median(nn)) if len(nn) else 0.0


_NEAR_K = 64  # centres listed per frame above EXACT_CENTRES
EXACT_CENTRES = 320
"""Levels of at most this many centres test every segment against every centre (exact);
larger ones against the `_NEAR_K` nearest (see `center_links`)."""
_PAIR_CHUNK = 16384


@partial(jax.jit, static_argnames=("max_len", "chunk", "near"))
def _clearance_kernel(xy, next_hop, center_frames, iu, ju, floor, max_len: int, chunk: int,
                      near: int):  # fmt: skip
    """Per pair (iu[p], ju[p]): ``(clear, unsure)``. ``clear``: the least 2-D distance
    from the polyline of the geodesic path between the two centres' frames to a listed
    centre other than the two (the ``near`` centres nearest each segment's start;
    ``near >= c`` lists them all); the walk stops once it is below ``floor``, so values
    ≥ ``floor`` are exact and smaller ones only say so; −inf when unreachable.
    ``unsure``: some walked segment reached past its list (an unlisted centre might be
    nearer). Pairs run ``chunk`` at a time."""
    c = center_frames.shape[0]
    pos = xy[center_frames]
    inf = jnp.asarray(jnp.inf, xy.dtype)
    if near >= c:  # exact: every centre on every list
        near_idx = jnp.broadcast_to(jnp.arange(c, dtype=jnp.int32), (xy.shape[0], c))
        cover = jnp.full(xy.shape[0], jnp.inf, xy.dtype)
    else:
        neg, near_idx = jax.lax.top_k(-_sq_dists(xy, pos), near)  # each frame's nearest
        cover = jnp.sqrt(jnp.maximum(-neg[:, -1], 0.0))

    def seg_clear(f, g, pi, pj, fi, fj):
        """Least distance from segment xy[f]→xy[g] to a listed centre other than pi, pj,
        and whether an unlisted one could be nearer than ``floor``."""
        a, b = xy[f], xy[g]
        ab = b - a
        L2 = jnp.sum(ab * ab, axis=-1)
        ids = near_idx[f]  # (n, kk)
        q = pos[ids]  # (n, kk, 2)
        t = jnp.sum((q - a[:, None, :]) * ab[:, None, :], axis=-1)
        t = t / jnp.where(L2 > 0, L2, 1.0)[:, None]
        t = jnp.clip(t, 0.0, 1.0)
        closest = a[:, None, :] + t[..., None] * ab[:, None, :]
        dist = jnp.sqrt(jnp.sum(jnp.square(q - closest), axis=-1))
        of = center_frames[ids]
        other = (ids != pi[:, None]) & (ids != pj[:, None])
        other &= (of != fi[:, None]) & (of != fj[:, None])
        # a centre within floor of the segment lies within floor + |ab| of its start:
        # the list settles the segment only when it reaches that far
        return jnp.min(jnp.where(other, dist, inf), axis=1), cover[f] <= floor + jnp.sqrt(L2)

    def one_chunk(args):
        pi, pj = args
        fi, fj = center_frames[pi], center_frames[pj]

        def cond(s):
            return jnp.any(s[1]) & (s[4] < max_len)

        def body(s):
            cur, active, clear, unsure, step = s
            nxt = next_hop[cur, fj]
            unreachable = nxt < 0
            nxt = jnp.where(unreachable, cur, nxt)
            d, far = seg_clear(cur, nxt, pi, pj, fi, fj)
            clear = jnp.where(active, jnp.minimum(clear, jnp.where(unreachable, -inf, d)), clear)
            unsure = unsure | (active & far & ~unreachable)
            active = active & (clear >= floor) & (nxt != fj)
            return jnp.where(active, nxt, cur), active, clear, unsure, step + 1

        same = fi == fj
        init = (fi, ~same, jnp.where(same, -inf, inf), jnp.zeros_like(same), jnp.int32(0))
        _, active, clear, unsure, _ = jax.lax.while_loop(cond, body, init)
        return jnp.where(active, -inf, clear), unsure  # cut short by max_len: unreachable

    n = iu.shape[0]
    pad = (-n) % chunk
    pi = jnp.pad(iu, (0, pad)).reshape(-1, chunk)
    pj = jnp.pad(ju, (0, pad)).reshape(-1, chunk)
    clear, unsure = jax.lax.map(one_chunk, (pi, pj))
    return clear.reshape(-1)[:n], unsure.reshape(-1)[:n]


def _pair_clearance(embedding, geodesics, center_frames, floor: float, near: int):
    """``(iu, ju, clear, unsure)`` over the pairs i < j (`_clearance_kernel`), chunked to
    ~64 MB per step."""
    cf = np.asarray(center_frames, np.int32)
    c = len(cf)
    iu, ju = np.triu_indices(c, 1)
    kk = c if near >= c else near
    chunk = int(max(1, min(_PAIR_CHUNK, len(iu), (1 << 22) // max(kk, 1))))
    nh = jnp.asarray(geodesics.next_hop)
    xy = jnp.asarray(embedding)
    clear, unsure = _clearance_kernel(
        xy, nh, jnp.asarray(cf), jnp.asarray(iu, jnp.int32), jnp.asarray(ju, jnp.int32),
        jnp.asarray(floor, xy.dtype), nh.shape[0] + 1, chunk, int(near),
    )  # fmt: skip
    return iu, ju, np.asarray(clear, np.float64), np.array(unsure)


@checked
def link_clearance(
    embedding: Float[Array, "T 2"], geodesics, center_frames: Int[Array, " c"], *,
    floor: float = 0.0,
) -> np.ndarray:  # fmt: skip
    """How far each pair's geodesic path keeps from the other centres (seed §4): for
    centres i, j the least 2-D distance from the polyline of the path between their
    frames to a centre other than i and j, exact (every centre looked at). i and j are
    linked at radius ρ exactly when ``clearance[i, j] >= ρ``, so one pass answers every
    ρ (`link_radius_sweep`). A pair's walk stops once it is below ``floor``: values ≥
    ``floor`` are exact, smaller ones only say so. Unreachable pairs and the diagonal
    are −inf.

    **Returns:** ``(c, c)`` symmetric float64."""
    c = len(np.asarray(center_frames))
    out = np.full((c, c), -np.inf)
    if c < 2:
        return out
    iu, ju, clear, _ = _pair_clearance(embedding, geodesics, center_frames, float(floor), c)
    out[iu, ju] = out[ju, iu] = clear
    return out


def _components(adj: np.ndarray) -> np.ndarray:
    """Component label of each centre of a symmetric (c, c) bool adjacency."""
    from scipy.sparse import csr_array
    from scipy.sparse.csgraph import connected_components

    return connected_components(csr_array(np.asarray(adj, bool)), directed=False)[1]


@checked
def center_links(
    embedding: Float[Array, "T 2"],
    geodesics,
    center_frames: Int[Array, " c"],
    rho: float,
    *,
    bridge: bool = False,
    exact: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Links between centres (seed §4): i—j when the geodesic path between their frames,
    drawn in 2-D as the polyline through its frames, passes no other centre within ρ.
    Pairs whose path is unreachable are never linked.

    ``exact`` (default: levels of at most `EXACT_CENTRES` = 320 centres, the ones the
    ρ experiment sweeps) tests every segment against every centre. Otherwise each
    segment is tested against the 64 centres nearest its start frame and one reaching
    past them counts as blocked:
    conservative, every link passes the rule but some it allows are missing (cost
    O(c²·64) instead of O(c³); on AnimFace's levels of 640 and 1 280 centres 9 634 of
    the rule's 24 297 and 19 728 of its 80 224 links, in 0.4 s instead of 2.5 s and
    1.3 s instead of 13 s).

    With ``bridge`` the cheapest geodesic link between components is added while the
    link graph is disconnected but the centres are reachable in the frame graph
    (outside the paper's rule; off by default in `build_hierarchy`).

    **Returns:** ``(links, bridges)``, both (c, c) symmetric bool with a False diagonal.
    Vectorised over the c(c−1)/2 pairs; the walk stops when every pair is blocked or
    arrived, so its length is that of the longest *unblocked* path.
    """
    cf = np.asarray(center_frames, dtype=np.int32)
    c = len(cf)
    if c < 2:
        return np.zeros((c, c), bool), np.zeros((c, c), bool)
    exact = c <= EXACT_CENTRES if exact is None else bool(exact)
    iu, ju, clear, unsure = _pair_clearance(
        embedding, geodesics, cf, float(rho), c if exact else _NEAR_K
    )
    links = np.zeros((c, c), bool)
    links[iu, ju] = (clear >= rho) & ~unsure  # unsure counts as blocked: conservative
    links |= links.T
    return links, (add_bridges(links, geodesics, cf) if bridge else np.zeros_like(links))


def add_bridges(links: np.ndarray, geodesics, center_frames) -> np.ndarray:
    """Bridges, added in place to ``links`` ``(c, c)``: while the link graph is in pieces
    that the frame graph joins, the smallest piece is joined to its geodesically nearest
    centre (outside the paper's rule). **Returns:** the bridges ``(c, c)`` bool."""
    cf = np.asarray(center_frames, np.int64)
    bridges = np.zeros_like(links)
    D = np.asarray(geodesics.distances)[np.ix_(cf, cf)].astype(np.float64)
    np.fill_diagonal(D, np.inf)
    comp = _components(links)  # once; each bridge then merges two labels
    while True:
        roots, sizes = np.unique(comp, return_counts=True)
        if len(roots) == 1:
            break
        inside = comp == roots[np.argmin(sizes)]
        sub = D[np.ix_(inside, ~inside)]
        if not np.isfinite(sub).any():
            break  # the frame graph itself is disconnected here
        a, b = np.unravel_index(np.argmin(sub), sub.shape)
        i, j = np.flatnonzero(inside)[a], np.flatnonzero(~inside)[b]
        links[i, j] = links[j, i] = True
        bridges[i, j] = bridges[j, i] = True
        comp[inside] = comp[j]
    return bridges


@checked
def link_components(level: Level) -> np.ndarray:
    """The piece (connected group of the level's links) of each centre, ``(c,)`` int
    labels 0…: one label when every centre reaches every other through links."""
    if level.links is None:
        raise FxspaceError("this level has no links")
    return _components(level.links)


@checked
def link_graph_connected(level: Level) -> bool:
    """Whether the level's link graph is connected."""
    if level.links is None:
        raise FxspaceError("this level has no links")
    return len(np.unique(_components(level.links))) == 1


@checked
def link_pairs(links) -> tuple[np.ndarray, np.ndarray]:
    """The linked pairs ``(i, j)`` with ``i < j`` of a level's links: a dense ``(c, c)``
    bool matrix (`Level`) or a sparse ``csr_array`` (`SparseLevel`), without densifying
    the sparse one (for drawing the links of 100 000 centres)."""
    if links is None:
        raise FxspaceError("links is None: this level has no links (build it with geodesics)")
    if hasattr(links, "tocoo"):
        m = links.tocoo()
        keep = (m.row < m.col) & (np.asarray(m.data) != 0)
        return np.asarray(m.row[keep], np.int64), np.asarray(m.col[keep], np.int64)
    L = np.asarray(links)
    if L.ndim != 2 or L.shape[0] != L.shape[1] or L.dtype.kind not in "biu":
        raise FxspaceError(
            f"links must be a (c, c) bool matrix or a csr_array, got {type(links).__name__} "
            f"of shape {L.shape}"
        )
    i, j = np.nonzero(np.triu(L, 1))
    return i.astype(np.int64), j.astype(np.int64)


class LinkRadiusSweep(NamedTuple):
    """The link radius experiment of Kim & Jung §4.2 (`link_radius_sweep`).

    **Fields:** `scales` ``(S,)`` (ρ = scale × the level's median centre spacing);
    `levels` ``(L,)`` the swept level indices and `centres` their sizes; per level and
    scale ``(L, S)``: `radii` (ρ), `links` (pairs linked), `components` (groups of
    centres the links join) and `coverage` (the fraction of centre pairs a route can
    join through links: 1 when the level is connected).
    """

    scales: np.ndarray
    levels: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    links: np.ndarray
    components: np.ndarray
    coverage: np.ndarray


def _coverage(labels: np.ndarray) -> float:
    c = len(labels)
    if c < 2:
        return 1.0
    sizes = np.unique(labels, return_counts=True)[1].astype(np.float64)
    return float(np.sum(sizes * (sizes - 1)) / (c * (c - 1)))


@checked
def link_radius_sweep(
    hierarchy: Hierarchy,
    geodesics,
    scales=LINK_SCALES,
    *,
    max_centres: int | None = 320,
) -> LinkRadiusSweep:
    """Links by the paper's rule (no bridges, exact: one `link_clearance` pass per level)
    at each ρ of ``scales`` on every level with at most ``max_centres`` centres: how many
    links, how many groups they leave, and the fraction of centre pairs a route can join
    (Kim & Jung §4.2: "the circle's radius is set by experiment"); `choose_link_scale`
    reads the answer off it.

    **Example:** ``sw = fx.navigation.link_radius_sweep(h, space.geodesics)``
    """
    return _sweep(hierarchy, geodesics, scales, max_centres)[0]


def _sweep(hierarchy, geodesics, scales, max_centres):
    """`link_radius_sweep` and the swept levels' clearances ``{level: (c, c)}``."""
    sc = np.asarray(scales, np.float64).reshape(-1)
    if not len(sc) or not np.all(np.isfinite(sc)) or np.any(sc < 0):
        raise FxspaceError(f"scales must be finite numbers >= 0, got {scales!r}")
    x = np.asarray(hierarchy.embedding)
    idx = [i for i, lv in enumerate(hierarchy.levels)
           if max_centres is None or lv.n_clusters <= max_centres]  # fmt: skip
    if not idx:
        raise FxspaceError(f"no level has at most max_centres={max_centres} centres")
    shape = (len(idx), len(sc))
    radii, coverage = np.zeros(shape), np.zeros(shape)
    links, comps = np.zeros(shape, np.int64), np.zeros(shape, np.int64)
    clears = {}
    for a, li in enumerate(idx):
        frames = hierarchy.levels[li].center_frames
        radii[a] = [default_link_radius(x[frames], float(s)) for s in sc]
        # one exact pass answers every ρ: linked at ρ ⇔ clearance ≥ ρ
        clear = clears[li] = link_clearance(x, geodesics, frames, floor=float(np.min(radii[a])))
        for b, rho in enumerate(radii[a]):
            lk = clear >= rho
            np.fill_diagonal(lk, False)
            labels = _components(lk)
            links[a, b] = int(lk.sum() // 2)
            comps[a, b] = len(np.unique(labels))
            coverage[a, b] = _coverage(labels)
    sizes = np.asarray([hierarchy.levels[i].n_clusters for i in idx])
    return LinkRadiusSweep(sc, np.asarray(idx), sizes, radii, links, comps, coverage), clears


@checked
def choose_link_scale(sweep: LinkRadiusSweep) -> float:
    """The largest ρ scale of ``sweep`` at which every swept level stays in one piece
    (coverage 1): the widest circles, so the fewest links that pass by another centre,
    that still let every centre reach every other. When no scale joins every level, the
    largest scale with the best worst-level coverage (the levels left in pieces then
    need bridges, ``build_hierarchy(bridges=True)``, to route across them)."""
    worst = np.round(np.min(np.asarray(sweep.coverage), axis=0), 9)
    return float(sweep.scales[np.flatnonzero(worst == worst.max())[-1]])
