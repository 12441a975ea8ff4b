"""Links between the centres of one hierarchy level (seed paper §4).

Two centres are *linked* when the geodesic (frame-graph) path between their frames
passes no frame within 2-D distance ρ of any other centre; ρ defaults to half the
median nearest-neighbour spacing of the level's centres. Should the unblocked links
leave the level disconnected while the frame graph is connected, the cheapest
(geodesic) link between components is added (a *bridge*) so that every centre stays
reachable.
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
    "LINK_SCALES",
    "LinkRadiusSweep",
    "center_links",
    "choose_link_scale",
    "default_link_radius",
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


_NEAR_K = 16
_PAIR_CHUNK = 16384


@partial(jax.jit, static_argnames=("max_len", "chunk"))
def _links_kernel(xy, next_hop, center_frames, iu, ju, rho, max_len: int, chunk: int):
    """Linked flag of each pair (iu[p], ju[p]); pairs are processed ``chunk`` at a time."""
    c = center_frames.shape[0]
    pos = xy[center_frames]
    kk = min(_NEAR_K, c)
    neg, near_idx = jax.lax.top_k(-_sq_dists(xy, pos), kk)  # nearest centres of every frame
    near_d = jnp.sqrt(jnp.maximum(-neg, 0.0))
    # when fewer than _NEAR_K centres exist the list covers them all
    cover = near_d[:, -1] if kk == _NEAR_K else jnp.full(xy.shape[0], jnp.inf, xy.dtype)

    def seg_blocked(f, g, pi, pj, fi, fj):
        """Does segment xy[f]→xy[g] pass within rho of a centre other than pi, pj?"""
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
        hit = jnp.any(other & (dist < rho), axis=1)
        # a centre within rho of the segment lies within rho + |ab| of its start: if the
        # near list does not reach that far it may miss one, so count the pair as blocked
        uncovered = cover[f] <= rho + jnp.sqrt(L2)
        return hit | uncovered

    def one_chunk(args):
        pi, pj = args
        fi, fj = center_frames[pi], center_frames[pj]

        def cond(s):
            _, active, _, step = s
            return jnp.any(active) & (step < max_len)

        def body(s):
            cur, active, blocked, step = s
            nxt = next_hop[cur, fj]
            unreachable = nxt < 0
            nxt = jnp.where(unreachable, cur, nxt)
            blk = blocked | (active & (unreachable | seg_blocked(cur, nxt, pi, pj, fi, fj)))
            active = active & ~blk & (nxt != fj)
            return jnp.where(active, nxt, cur), active, blk, step + 1

        active0 = fi != fj
        _, active, blocked, _ = jax.lax.while_loop(
            cond, body, (fi, active0, fi == fj, jnp.asarray(0, jnp.int32))
        )
        return ~blocked & ~active

    n = iu.shape[0]
    pad = (-n) % chunk
    pi = jnp.pad(iu, (0, pad)).reshape(-1, chunk)
    pj = jnp.pad(ju, (0, pad)).reshape(-1, chunk)
    ok = jax.lax.map(one_chunk, (pi, pj)).reshape(-1)[:n]
    links = jnp.zeros((c, c), bool).at[iu, ju].set(ok)
    return links | links.T


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
) -> tuple[np.ndarray, np.ndarray]:
    """Links between centres (seed §4): i—j when the geodesic path between their frames,
    drawn in 2-D as the polyline through its frames, passes no other centre within ρ.
    Pairs whose path is unreachable are never linked. Each segment is tested exactly
    against the 16 centres nearest its start frame; a segment so long that a farther
    centre could be within ρ counts as blocked (conservative).

    With ``bridge`` the cheapest geodesic link between components is added while the
    link graph is disconnected but the centres are reachable in the frame graph.

    **Returns:** ``(links, bridges)``, both (c, c) symmetric bool with a False diagonal.
    Vectorised over the c(c−1)/2 pairs; the walk stops when every pair is blocked or
    arrived, so its length is that of the longest *unblocked* path.
    """
    cf = np.asarray(center_frames, dtype=np.int32)
    c = len(cf)
    if c < 2:
        return np.zeros((c, c), bool), np.zeros((c, c), bool)
    nh = jnp.asarray(geodesics.next_hop)
    T = nh.shape[0]
    iu, ju = np.triu_indices(c, 1)
    chunk = int(min(_PAIR_CHUNK, len(iu)))
    xy = jnp.asarray(embedding)
    links = np.array(
        _links_kernel(
            xy,
            nh,
            jnp.asarray(cf),
            jnp.asarray(iu, jnp.int32),
            jnp.asarray(ju, jnp.int32),
            jnp.asarray(rho, xy.dtype),
            T + 1,
            chunk,
        )
    )
    bridges = np.zeros_like(links)
    if bridge:
        D = np.asarray(geodesics.distances)[np.ix_(cf, cf)].astype(np.float64)
        np.fill_diagonal(D, np.inf)
        comp = _components(links)  # once; each bridge then merges two labels
        while True:
            roots, sizes = np.unique(comp, return_counts=True)
            if len(roots) == 1:
                break
            # connect the smallest component to its geodesically nearest centre
            inside = comp == roots[np.argmin(sizes)]
            sub = D[np.ix_(inside, ~inside)]
            if not np.isfinite(sub).any():
                break  # the frame graph itself is disconnected here
            a, b = np.unravel_index(np.argmin(sub), sub.shape)
            i, j = np.flatnonzero(inside)[a], np.flatnonzero(~inside)[b]
            links[i, j] = links[j, i] = True
            bridges[i, j] = bridges[j, i] = True
            comp[inside] = comp[j]
    return links, bridges


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
    """Links by the paper's rule (no bridges) at each ρ of ``scales`` on every level with
    at most ``max_centres`` centres: how many links, how many groups they leave, and the
    fraction of centre pairs a route can still join (Kim & Jung §4.2: "the circle's
    radius is set by experiment"). `choose_link_scale` reads the answer off it.

    **Example:** ``sw = fx.navigation.link_radius_sweep(h, space.geodesics)``
    """
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
    for a, li in enumerate(idx):
        frames = hierarchy.levels[li].center_frames
        for b, s in enumerate(sc):
            radii[a, b] = default_link_radius(x[frames], float(s))
            lk, _ = center_links(x, geodesics, frames, radii[a, b], bridge=False)
            labels = _components(lk)
            links[a, b] = int(lk.sum() // 2)
            comps[a, b] = len(np.unique(labels))
            coverage[a, b] = _coverage(labels)
    sizes = np.asarray([hierarchy.levels[i].n_clusters for i in idx])
    return LinkRadiusSweep(sc, np.asarray(idx), sizes, radii, links, comps, coverage)


@checked
def choose_link_scale(sweep: LinkRadiusSweep) -> float:
    """The largest ρ scale of ``sweep`` at which every swept level stays in one piece
    (coverage 1): the widest circles, so the fewest links that pass by another centre,
    that still let every centre reach every other. When no scale joins every level, the
    largest scale with the best worst-level coverage (the levels left in pieces then
    need bridges, ``build_hierarchy(bridges=True)``, to route across them)."""
    worst = np.round(np.min(np.asarray(sweep.coverage), axis=0), 9)
    return float(sweep.scales[np.flatnonzero(worst == worst.max())[-1]])
