"""Links between the centres of one hierarchy level (Kim & Jung §4.2), at every size.

Two centres are *linked* when the shortest path between their frames, drawn in 2-D as
the polyline through its frames, passes within ρ of no other centre; ρ is a scale × the
level's median nearest-centre spacing, the scale chosen by the paper's experiment
(`fxspace.navigation._rho`: `link_radius_sweep`, `choose_link_scale`). Written once
against the frames' *paths* (`fxspace.expression.Paths`: `Geodesics` or a
`NeighbourGraph`):

- a level of at most `EXACT_CENTRES` centres: every pair, every segment against every
  centre (exact), walking each pair's path along the shortest-path trees into the
  centres (`Paths.toward`, in batches of targets);
- a larger level: each centre's `LinkRule.near` nearest centres as candidate pairs and
  each segment against the centres nearest it (a near list per frame: conservative,
  every link passes the rule, some it allows are missing);
- the level where every frame is a centre: a path with an interior frame passes that
  frame, itself a centre, so only the graph's steps that are shortest paths
  (`Paths.steps`) can be links, each tested against every frame near it with a k-d
  tree (exact, coarse to fine: `fxspace.navigation._segments`).

Bridges (the cheapest geodesic links joining the pieces a level is left in, outside the
rule) only on request (`LinkRule(bridges=True)`).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import checked
from fxspace.cluster import pad_rows
from fxspace.cluster import squared_distances as _sq_dists
from fxspace.errors import FxspaceError
from fxspace.navigation._level import LinkRadiusSweep, pair_csr
from fxspace.navigation._segments import segments_near_points

__all__ = [
    "EXACT_CENTRES",
    "LINK_SCALES",
    "LinkRule",
    "LinkRadiusSweep",
    "center_links",
    "default_link_radius",
    "link_clearance",
]

LINK_SCALES = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)
"""The ρ scales `link_radius_sweep` tries by default (× each level's centre spacing)."""

EXACT_CENTRES = 320
"""Levels of at most this many centres test every pair, every segment against every
centre (exact); larger ones the `LinkRule.near` nearest (see the module docstring)."""

_PAIR_CHUNK = 16384
_SHARE_BUDGET = 1 << 22  # frames × padded centres up to which the levels share compiles
_HOP_BUDGET = 1 << 25  # entries of the (targets × frames) next-hop rows held at once


@dataclasses.dataclass(frozen=True)
class LinkRule:
    """How a level's links are made (Kim & Jung §4.2).

    **Fields:**

    - `rho`: ρ = `rho` × the level's median nearest-centre spacing; ``"experiment"``
      (default): the paper's experiment chooses the scale (`link_radius_sweep` over
      `scales` on the levels of at most `sweep_max_centres` centres, `choose_link_scale`:
      the largest scale that keeps them all in one piece).
    - `bridges`: False (default): the rule alone (a level may fall into pieces that no
      route joins); True: the pieces are joined by their geodesically cheapest pairs
      (``Level.bridges``, outside the rule).
    - `exact_centres`: levels up to this size are exact (every pair, every centre);
      `near`: above it, candidate pairs and near lists of this many centres.
    - `max_centres`: levels with more centres get no links (None: every level).
    """

    rho: float | Literal["experiment"] = "experiment"
    scales: tuple[float, ...] = LINK_SCALES
    sweep_max_centres: int = 320
    bridges: bool = False
    exact_centres: int = EXACT_CENTRES
    near: int = 64
    max_centres: int | None = None

    def __post_init__(self):
        if isinstance(self.rho, str):
            if self.rho != "experiment":
                raise FxspaceError(
                    f"rho_scale / LinkRule.rho must be a number >= 0 or 'experiment', got "
                    f"{self.rho!r}"
                )
        elif not float(self.rho) >= 0:
            raise FxspaceError(f"LinkRule.rho must be >= 0 or 'experiment', got {self.rho}")
        if int(self.near) < 1 or int(self.exact_centres) < 2:
            raise FxspaceError("LinkRule: need near >= 1 and exact_centres >= 2")


@checked
def default_link_radius(points: Float[Array, "c 2"], scale: float = 0.5) -> float:
    """ρ = ``scale`` × median nearest-neighbour distance between the centres' positions
    (the level's spacing; coincident centres aside)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    if scale < 0:
        raise FxspaceError(f"scale must be >= 0, got {scale}")
    if len(p) < 2:
        return 0.0
    nn = cKDTree(p).query(p, k=2)[0][:, 1]
    nn = nn[np.isfinite(nn) & (nn > 0)]
    return float(scale * np.median(nn)) if len(nn) else 0.0


@partial(jax.jit, static_argnames=("near",))
def _near_lists(xy, pos, valid, near: int):
    """Each frame's ``near`` nearest centres among the valid (unpadded) ones and the
    distance to the last of them: ``(near_idx, cover)``."""
    d2 = jnp.where(valid[None, :], _sq_dists(xy, pos), jnp.inf)
    neg, near_idx = jax.lax.top_k(-d2, near)
    return near_idx, jnp.sqrt(jnp.maximum(-neg[:, -1], 0.0))


@partial(jax.jit, static_argnames=("max_len", "exact"))
def _clearance_kernel(xy, hop, center_frames, valid, near_idx, cover, pi, pj, pr, floor,
                      max_len: int, exact: bool):  # fmt: skip
    """Per pair (pi[p], pj[p]) of one chunk: ``(clear, unsure)``. The walk goes from pi's
    frame along ``hop[pr[p]]`` (the shortest-path tree into pj's frame). ``clear``: the
    least 2-D distance from the walked polyline to a listed centre other than the two
    (``exact``: every valid centre; else the ``near_idx`` row of each segment's start,
    `_near_lists`); the walk stops once it is below ``floor``, so values ≥ ``floor`` are
    exact and smaller ones only say so; −inf when unreachable. ``unsure``: a walked
    segment reached past its list (an unlisted centre might be nearer). The centres are
    padded (``valid`` marks the real ones) and pairs with pi = pj are padding, so the
    levels share a compile."""
    c = center_frames.shape[0]
    pos = xy[center_frames]
    inf = jnp.asarray(jnp.inf, xy.dtype)

    def seg_clear(f, g, fi, fj):
        a, b = xy[f], xy[g]
        ab = b - a
        L2 = jnp.sum(ab * ab, axis=-1)
        ids = (jnp.broadcast_to(jnp.arange(c, dtype=jnp.int32), (f.shape[0], c)) if exact
               else near_idx[f])  # fmt: skip
        q = pos[ids]
        t = jnp.sum((q - a[:, None, :]) * ab[:, None, :], axis=-1)
        t = jnp.clip(t / jnp.where(L2 > 0, L2, 1.0)[:, None], 0.0, 1.0)
        dist = jnp.sqrt(jnp.sum(jnp.square(q - (a[:, None, :] + t[..., None] * ab[:, None, :])),
                                axis=-1))  # fmt: skip
        of = center_frames[ids]
        other = (ids != pi[:, None]) & (ids != pj[:, None]) & valid[ids]
        other &= (of != fi[:, None]) & (of != fj[:, None])
        if exact:
            return jnp.min(jnp.where(other, dist, inf), axis=1), jnp.zeros(f.shape, bool)
        # a centre within floor of the segment lies within floor + |ab| of its start
        return jnp.min(jnp.where(other, dist, inf), axis=1), cover[f] <= floor + jnp.sqrt(L2)

    fi, fj = center_frames[pi], center_frames[pj]

    def cond(s):
        return jnp.any(s[1]) & (s[4] < max_len)

    def body(s):
        cur, active, clear, unsure, step = s
        nxt = hop[pr, cur]
        unreachable = nxt < 0
        nxt = jnp.where(unreachable, cur, nxt)
        d, far = seg_clear(cur, nxt, fi, fj)
        clear = jnp.where(active, jnp.minimum(clear, jnp.where(unreachable, -inf, d)), clear)
        unsure = unsure | (active & far & ~unreachable)
        active = active & (clear >= floor) & (nxt != fj)
        return jnp.where(active, nxt, cur), active, clear, unsure, step + 1

    same = fi == fj  # padding pairs: pi = pj
    init = (fi, ~same, jnp.where(same, -inf, inf), jnp.zeros_like(same), jnp.int32(0))
    _, active, clear, unsure, _ = jax.lax.while_loop(cond, body, init)
    return jnp.where(active, -inf, clear), unsure  # cut short by max_len: unreachable


def _padded(v, size: int, fill=0) -> np.ndarray:
    v = np.asarray(v)
    return np.concatenate([v, np.full((size - len(v), *v.shape[1:]), fill, v.dtype)])


def _pair_clearance(xy, paths, cf, iu, ju, floor: float, near: int, want_d: bool = False):
    """``(clear, unsure, length)`` of the pairs (iu, ju) (`_clearance_kernel`), walking
    the shortest-path trees into the ju centres' frames, a batch of targets at a time;
    with ``want_d`` also the ``(c, c)`` geodesic distances between all centres. On a
    few thousand frames (`_SHARE_BUDGET`) the centres are padded to `pad_rows` rows, the
    target batches likewise and the pairs to whole chunks, so the levels of a hierarchy
    share a few compiles; on more (long walks, a compile is cheap beside them) the
    chunks hold only real pairs."""
    c = len(cf)
    T = int(paths.num_frames)
    share = T * pad_rows(c) <= _SHARE_BUDGET
    size = pad_rows(c) if share else c
    exact = near >= c
    clear = np.full(len(iu), -np.inf)
    unsure = np.zeros(len(iu), bool)
    length = np.full(len(iu), np.inf)
    D = np.full((c, c), np.inf) if want_d else None
    xyj = jnp.asarray(xy)
    cfp = _padded(np.asarray(cf, np.int32), size)
    cfj, valid = jnp.asarray(cfp), jnp.asarray(np.arange(size) < c)
    if exact:  # no near lists (placeholders)
        near_idx = jnp.asarray(np.zeros((1, 1), np.int32))
        cover = jnp.asarray(np.full(1, np.inf, xyj.dtype))
        chunk = min(_PAIR_CHUNK, max(size * (size - 1) // 2, 1), (1 << 22) // size)
    else:
        near_idx, cover = _near_lists(xyj, jnp.asarray(np.asarray(xyj)[cfp]), valid, int(near))
        chunk = min(_PAIR_CHUNK, (1 << 22) // max(int(near), 1))
    targets = np.unique(ju) if not want_d else np.arange(c)
    per = max(1, _HOP_BUDGET // max(T, 1))
    for s in range(0, len(targets), per):
        batch = targets[s : s + per]
        dist, hop = paths.toward(cf[batch])
        if want_d:
            D[batch] = dist[:, cf]
        row = np.full(c, -1, np.int64)
        row[batch] = np.arange(len(batch))
        sel = np.flatnonzero(row[ju] >= 0)
        if not len(sel):
            continue
        rows = max(len(batch), min(pad_rows(len(batch)), per)) if share else len(batch)
        hopj = jnp.asarray(_padded(hop, rows, -1))
        step = chunk if share else max(1, min(chunk, len(sel)))
        for a in range(0, len(sel), step):
            part = sel[a : a + step]
            cl, un = _clearance_kernel(
                xyj, hopj, cfj, valid, near_idx, cover,
                *(jnp.asarray(_padded(v, step).astype(np.int32))
                  for v in (iu[part], ju[part], row[ju[part]])),
                jnp.asarray(floor, xyj.dtype), T + 1, bool(exact),
            )  # fmt: skip
            clear[part] = np.asarray(cl, np.float64)[: len(part)]
            unsure[part] = np.asarray(un)[: len(part)]
        length[sel] = dist[row[ju[sel]], cf[iu[sel]]]
    return clear, unsure, length, D


def _check(xy, paths, center_frames):
    xy = np.asarray(xy, np.float64)
    if not hasattr(paths, "toward"):
        raise FxspaceError(
            f"paths must be the frames' Geodesics or NeighbourGraph (fxspace.expression.Paths),"
            f" got {type(paths).__name__}"
        )
    T = int(paths.num_frames)
    if xy.ndim != 2 or xy.shape[0] != T:
        raise FxspaceError(
            f"embedding must be (T, 2) with T = {T} (the paths' frames), got shape {xy.shape}"
        )
    cf = np.asarray(center_frames, np.int64).reshape(-1)
    if cf.size and not (cf.min() >= 0 and cf.max() < T):
        raise FxspaceError(f"center_frames must index the {T} frames")
    return xy, cf


@checked
def link_clearance(
    embedding: Float[Array, "T 2"], paths, center_frames: Int[Array, " c"], *,
    floor: float = 0.0,
) -> np.ndarray:  # fmt: skip
    """How far each pair's shortest path keeps from the other centres (Kim & Jung §4.2):
    for centres i, j the least 2-D distance from the polyline of the path between their
    frames to a centre other than i and j, every centre looked at. i and j are linked
    at radius ρ exactly when ``clearance[i, j] >= ρ``, so one pass answers every ρ
    (`link_radius_sweep`). A pair's walk stops once it is below ``floor``: values ≥
    ``floor`` are exact, smaller ones only say so. Unreachable pairs and the diagonal are
    −inf. ``paths``: the `Geodesics` or `NeighbourGraph` of the frames.

    **Returns:** ``(c, c)`` symmetric float64."""
    out, _ = _clearances(embedding, paths, center_frames, floor)
    return out


def _clearances(embedding, paths, center_frames, floor):
    xy, cf = _check(embedding, paths, center_frames)
    c = len(cf)
    out = np.full((c, c), -np.inf)
    if c < 2:
        return out, np.full((c, c), np.inf)
    iu, ju = np.triu_indices(c, 1)
    clear, _, _, D = _pair_clearance(xy, paths, cf, iu, ju, float(floor), c, want_d=True)
    out[iu, ju] = out[ju, iu] = clear
    return out, D


def _candidate_pairs(pos: np.ndarray, near: int) -> tuple[np.ndarray, np.ndarray]:
    """Unordered pairs i < j with j among i's ``near`` nearest (2-D) or the reverse."""
    from scipy.spatial import cKDTree

    c = len(pos)
    k = min(int(near) + 1, c)
    nb = cKDTree(pos).query(pos, k=k)[1][:, 1:]
    i = np.repeat(np.arange(c), nb.shape[1])
    j = nb.reshape(-1)
    a, b = np.minimum(i, j), np.maximum(i, j)
    keep = (a != b) & (b < c)
    key = np.unique(a[keep] * c + b[keep])
    return key // c, key % c


def _check_rho(rho: float) -> None:
    if not rho > 0:
        raise FxspaceError(
            f"rho must be > 0 on the level where every frame is a centre, got {rho}: the "
            "embedding's frames coincide"
        )


def step_blocks(xy, paths, rho: float):
    """``(i, j, length, blocked, rho)``: the graph's steps that are shortest paths and
    which of them pass another frame within ρ. A step blocked at ρ is blocked at every
    larger ρ, so these answer any ρ' ≥ ρ by testing only the rest (`_step_links`'s
    ``pre``): made at the smallest ρ the experiment may choose, beside the FCM levels."""
    _check_rho(rho)
    i, j, w = paths.steps()
    return i, j, w, segments_near_points(xy, i, j, rho), float(rho)


def _step_links(xy, paths, rho: float, pre=None):
    """The links of a level where every frame is a centre: the steps that are shortest
    paths whose segment passes no other frame within ρ (exact,
    `fxspace.navigation._segments`). ``(i, j, length)``. ``pre``: `step_blocks` at a
    ρ₀ ≤ ρ (only the steps it left clear are tested again)."""
    _check_rho(rho)
    if pre is None or not pre[4] <= rho:
        i, j, w = paths.steps()
        blocked = segments_near_points(xy, i, j, rho)
    else:
        i, j, w, blocked, rho0 = pre
        blocked = blocked.copy()
        if rho > rho0:
            rest = np.flatnonzero(~blocked)
            blocked[rest] = segments_near_points(xy, i[rest], j[rest], rho)
    return i[~blocked], j[~blocked], w[~blocked]


def _bridges(c: int, li, lj, ci, cj, cw):
    """Bridges joining the pieces of the links (li, lj) along candidate pairs (ci, cj) of
    geodesic length cw: a minimum spanning forest of the pieces (each joined by its
    cheapest pair). ``(i, j, length)``."""
    from scipy.sparse import csr_array
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    n, lab = connected_components(pair_csr(li, lj, np.ones(len(li), bool), c), directed=False)
    ok = np.isfinite(cw) & (lab[ci] != lab[cj])
    ci, cj, cw = ci[ok], cj[ok], cw[ok]
    if n == 1 or not len(ci):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    lo, hi = np.minimum(lab[ci], lab[cj]), np.maximum(lab[ci], lab[cj])
    order = np.lexsort((ci, cw, hi, lo))
    first = np.ones(len(order), bool)
    first[1:] = (lo[order][1:] != lo[order][:-1]) | (hi[order][1:] != hi[order][:-1])
    e = order[first]  # the cheapest pair between each two pieces
    rank = np.empty(len(e))
    rank[np.argsort(cw[e], kind="stable")] = np.arange(1, len(e) + 1)  # no zero weights
    mst = minimum_spanning_tree(csr_array((rank, (lo[e], hi[e])), shape=(n, n))).tocoo()
    pick = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(lo[e], hi[e], strict=True))}
    sel = e[[pick[(int(min(a, b)), int(max(a, b)))] for a, b in zip(mst.row, mst.col,
                                                                     strict=True)]]  # fmt: skip
    return ci[sel], cj[sel], cw[sel]


def level_links(xy, paths, center_frames, rho: float, rule: LinkRule, clear=None, D=None,
                pre=None):
    """``(links, bridges, lengths)`` ``csr_array``\\ s of one level (see the module
    docstring); ``clear``/``D``: the level's clearances and centre distances when the ρ
    experiment has them (the links are then read off them); ``pre``: on the level where
    every frame is a centre, its `step_blocks` at a ρ₀ ≤ ρ."""
    xy, cf = _check(xy, paths, center_frames)
    c = len(cf)
    T = int(paths.num_frames)
    if c == T and np.array_equal(cf, np.arange(T)):  # every frame a centre
        i, j, w = _step_links(xy, paths, rho, pre)
        cand = paths.steps() if rule.bridges else None
    else:
        if clear is None and c >= 2:
            exact = c <= rule.exact_centres
            iu, ju = (np.triu_indices(c, 1) if exact
                      else _candidate_pairs(xy[cf], rule.near))  # fmt: skip
            want = rule.bridges and c <= 4096
            cl, un, ln, D = _pair_clearance(xy, paths, cf, iu, ju, float(rho),
                                            c if exact else rule.near, want_d=want)  # fmt: skip
            keep = (cl >= rho) & ~un  # unsure counts as blocked: conservative
            i, j, w = iu[keep], ju[keep], ln[keep]
            if rule.bridges and D is None:
                D = np.full((c, c), np.inf)
                D[iu, ju] = ln
        elif c >= 2:
            iu, ju = np.triu_indices(c, 1)
            keep = clear[iu, ju] >= rho
            i, j, w = iu[keep], ju[keep], D[iu[keep], ju[keep]]
        else:
            i = j = np.zeros(0, np.int64)
            w = np.zeros(0)
        cand = None
        if rule.bridges and c >= 2:
            iu, ju = np.triu_indices(c, 1)
            cand = (iu, ju, np.minimum(D[iu, ju], D[ju, iu]))
    bi = bj = np.zeros(0, np.int64)
    bw = np.zeros(0)
    if rule.bridges and cand is not None:
        bi, bj, bw = _bridges(c, i, j, *cand)
    ai, aj = np.concatenate([i, bi]), np.concatenate([j, bj])
    links = pair_csr(ai, aj, np.ones(len(ai), bool), c)
    lengths = pair_csr(ai, aj, np.concatenate([w, bw]).astype(np.float64), c)
    return links, pair_csr(bi, bj, np.ones(len(bi), bool), c), lengths


@checked
def center_links(
    embedding: Float[Array, "T 2"],
    paths,
    center_frames: Int[Array, " c"],
    rho: float,
    *,
    bridge: bool = False,
    exact: bool | None = None,
) -> tuple[object, object]:
    """Links between centres (Kim & Jung §4.2): i—j when the shortest path between their
    frames, drawn in 2-D, passes no other centre within ρ. Unreachable pairs are never
    linked.

    **Arguments:** `embedding` ``(T, 2)``; `paths` the frames' ``Geodesics`` or
    `NeighbourGraph`; `center_frames` ``(c,)``; `rho`; `bridge` also join the pieces the
    rule leaves by their cheapest pairs (outside the rule); `exact` (default: levels of
    at most `EXACT_CENTRES` centres) every pair and every centre, else the conservative
    near test (module docstring).

    **Returns:** ``(links, bridges)``, ``(c, c)`` symmetric ``csr_array`` of bool."""
    c = len(np.asarray(center_frames).reshape(-1))
    n_exact = EXACT_CENTRES if exact is None else (max(c, 2) if exact else 2)
    rule = LinkRule(rho=float(rho), bridges=bool(bridge), exact_centres=n_exact)
    links, bridges, _ = level_links(embedding, paths, center_frames, float(rho), rule)
    return links, bridges
