"""Which 2-D segments pass within ρ of another point, exactly, at 10⁵–10⁶ segments.

The links of the level where every frame is a centre (Kim & Jung §4.2 at its finest)
are the graph's steps whose segment passes no other frame within ρ. Segments are long
against ρ (on a k-NN graph of 10⁵ frames the median step is ~200 ρ), so a test per
segment against every frame near its midpoint costs O(T²) overall. Here:

1. **Sure blocks** (where ρ is at least `_SURE_FROM` of the frames' median spacing).
   8 points on each segment: a frame (other than the segment's ends) within ρ of a point
   on the segment is within ρ of the segment, so the segment is blocked. There, most
   blocked segments go here; with a smaller ρ it blocks too few to pay for itself.
2. **Exact, for the rest.** Points every ``s = max(2ρ, 4 × the frames' median
   spacing)`` along the segment (ends included) and every frame within
   ``sqrt(ρ² + (s/2)²)`` of one of them (its 24 nearest, the whole ball where 24 do not
   exhaust it): a frame within ρ of the segment has its foot within ``s/2`` of a point,
   so it is among them; their exact segment distances decide. The points go in 8
   interleaved rounds, and a segment found blocked leaves: most segments that reach this
   pass are blocked (81 % on a 10⁵-frame k-NN graph), so it asks 2.4 M points there
   instead of 6.5 M. Cost: the segments' total length over ``s``, a few frames per
   point. Where the frames are few and the segments long, every segment against every
   frame instead, under jit, when that costs less; and where many segments leave each
   frame (an ε-graph of a few thousand frames: 2 × 10⁶ steps, each ~100 spacings long),
   origin by origin: around an origin, a frame at distance r can be within ρ of a
   segment only if the segment's direction is within asin(ρ / r) of the frame's, so a
   binary search among the segments sorted by angle finds the few pairs to measure
   exactly (`_fan_blocks`).

Both passes use one k-d tree over the frames (scipy ``cKDTree``, queried on every core).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_COARSE = 8  # points per segment in the sure-block pass
_BRUTE_PAIRS = 1 << 23  # segment-frame pairs per jit call of the brute pass
_BRUTE_PER_POINT = 500  # segment-frame pairs that cost about one point of the exact pass (measured)
_FAN_FROM = 128  # segments per origin from which the fan pass costs less than brute force
# (measured: the fan pays ~0.6 µs per frame and origin, brute force ~5 ns per pair)
_NEAREST = 24  # frames asked of each point in the exact pass (the whole ball past that)
_EXACT_SPACINGS = 4.0  # the exact pass's points at least this many spacings apart: fewer
# k-d tree calls, a few more frames each (measured on 10⁵ frames: 11.3 s against 16.8 s
# for 1 spacing and 8 nearest, 14.5 s for 8 spacings; the same blocks)
_BATCH = 1 << 21  # sample points per k-d tree call
_BALL_ENTRIES = 1 << 22  # frames of the whole-ball fallback listed at once (as Python
# ints: at 10⁶ frames one batch of dense balls listed at once took ~10 GB)
_ROUNDS = 8  # the exact pass's interleaved rounds (blocked segments leave after each)
_ORDER = (0, 4, 2, 6, 1, 5, 3, 7)  # bit-reversed: each round halves the gaps left
_SURE_FROM = 0.15  # the sure-block pass runs where ρ is at least this many spacings
# (measured on a 10⁵-frame k-NN graph: at ρ = 0.05 spacings it blocks 4 % and costs more
# than it saves, 12.4 s against 11.0 s for the exact pass alone; at 0.2: 6.9 against 6.8;
# at 0.5: 3.5 against 6.4; at 10⁶ frames and 0.05 spacings, 20 s of 225 saved)


def _segment_distance(q, a, v):
    L2 = np.maximum(np.sum(v * v, axis=1), 1e-300)
    t = np.clip(np.sum((q - a) * v, axis=1) / L2, 0.0, 1.0)
    return np.linalg.norm(q - (a + t[:, None] * v), axis=1)


def _samples(a, b, m):
    """``(owner, points)``: ``m[k]`` evenly spaced points on segment k, ends included."""
    own = np.repeat(np.arange(len(a)), m)
    start = np.repeat(np.cumsum(m) - m, m)
    frac = (np.arange(len(own)) - start) / np.maximum(m[own] - 1, 1)
    return own, a[own] + frac[:, None] * (b[own] - a[own])


def _batches(m: np.ndarray):
    """Slices of segments whose point counts ``m`` sum to about `_BATCH`."""
    edges = np.concatenate([[0], np.cumsum(m)])
    s = 0
    while s < len(m):
        e = int(np.searchsorted(edges, edges[s] + _BATCH, "right")) - 1
        e = min(max(e, s + 1), len(m))
        yield slice(s, e)
        s = e


def _sure_blocks(tree, xy, i, j, m, rho):
    """Which segments have a frame (not i, not j) within ρ of one of their ``m`` points."""
    out = np.zeros(len(i), bool)
    for sl in _batches(m):
        ii, jj = i[sl], j[sl]
        own, pts = _samples(xy[ii], xy[jj], m[sl])
        d, nb = tree.query(pts, k=min(3, len(xy)), distance_upper_bound=rho, workers=-1)
        d, nb = d.reshape(len(pts), -1), nb.reshape(len(pts), -1)
        hit = (d < rho) & (nb != ii[own][:, None]) & (nb != jj[own][:, None])
        out[sl.start + np.unique(own[hit.any(axis=1)])] = True
    return out


def _points(a, b, m, first: int, stride: int):
    """``(owner, points)``: points ``first, first + stride, …`` of the ``m[k]`` evenly
    spaced points on segment k (ends included; none where ``m[k] <= first``)."""
    n = np.maximum((m - first + stride - 1) // stride, 0)
    own = np.repeat(np.arange(len(a)), n)
    p = first + stride * (np.arange(len(own)) - np.repeat(np.cumsum(n) - n, n))
    frac = p / np.maximum(m[own] - 1, 1)
    return own, a[own] + frac[:, None] * (b[own] - a[own])


def _exact_blocks(tree, xy, i, j, rho, step):
    """Exactly which segments pass a frame (not i, not j) within ρ (module docstring):
    points every ``step`` (≥ 2ρ), each point's `_NEAREST` nearest frames within the
    reach, and the whole ball where they do not exhaust it. The points go in `_ROUNDS`
    interleaved rounds (every `_ROUNDS`-th point, in bit-reversed order), and a segment
    found blocked leaves: a blocked segment costs its points up to the round that finds
    it, a clear one (a link) all of them."""
    out = np.zeros(len(i), bool)
    if not len(i):
        return out
    reach = float(np.hypot(rho, 0.5 * step))
    length = np.linalg.norm(xy[j] - xy[i], axis=1)
    m = np.ceil(length / step).astype(np.int64) + 1
    k = min(_NEAREST, len(xy))
    live = np.arange(len(i))
    for first in _ORDER:
        live = live[~out[live]]
        now = live[m[live] > first]
        for sl in _batches((m[now] - first + _ROUNDS - 1) // _ROUNDS):
            idx = now[sl]
            own, pts = _points(xy[i[idx]], xy[j[idx]], m[idx], first, _ROUNDS)
            out[idx[_hits(tree, xy, i[idx], j[idx], own, pts, rho, reach, k)]] = True
    return out


def _hits(tree, xy, ii, jj, own, pts, rho, reach, k):
    """The segments (indices into ``ii``/``jj``) with a frame (not an end) within ρ,
    among the frames within ``reach`` of their points ``pts`` (owner ``own``): each
    point's k nearest, and the whole ball where they do not exhaust it (listed
    `_BALL_ENTRIES` frames at a time: a ball in a dense clump holds thousands)."""
    d, nb = tree.query(pts, k=k, distance_upper_bound=reach, workers=-1)
    d, nb = d.reshape(len(pts), -1), nb.reshape(len(pts), -1)
    full = np.flatnonzero(np.isfinite(d[:, -1]))  # the ball may hold more than k
    del d
    found = [own[_near_rows(xy, ii, jj, own, nb, rho)]]
    del nb
    if len(full):
        n = tree.query_ball_point(pts[full], reach, return_length=True, workers=-1)
        edges = np.concatenate([[0], np.cumsum(n)])
        s = 0
        while s < len(full):
            e = int(np.searchsorted(edges, edges[s] + _BALL_ENTRIES, "right")) - 1
            e = min(max(e, s + 1), len(full))
            rows = full[s:e]
            lists = tree.query_ball_point(pts[rows], reach, return_sorted=False, workers=-1)
            flat = np.fromiter((q for x in lists for q in x), np.int64, int(n[s:e].sum()))
            found.append(_near(xy, ii, jj, np.repeat(own[rows], n[s:e]), flat, rho))
            s = e
    return np.unique(np.concatenate(found))


_NEAR_ROWS = 1 << 15  # points a call of the compiled near test (one compile: one shape)


@jax.jit
def _near_kernel(xy, a_idx, b_idx, nb, rho):
    """Per point: whether one of its listed frames ``nb`` (``len(xy) − 1``: none; the
    segment's ends excluded) is strictly within ρ of the segment ``xy[a] → xy[b]``
    (`_segment_distance`'s formula, in ``xy``'s dtype)."""
    a = xy[a_idx]
    v = xy[b_idx] - a
    L2 = jnp.maximum(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1], 1e-300)
    q = xy[nb]
    w0, w1 = q[..., 0] - a[:, None, 0], q[..., 1] - a[:, None, 1]
    t = jnp.clip((w0 * v[:, None, 0] + w1 * v[:, None, 1]) / L2[:, None], 0.0, 1.0)
    dx = q[..., 0] - (a[:, None, 0] + t * v[:, None, 0])
    dy = q[..., 1] - (a[:, None, 1] + t * v[:, None, 1])
    other = (nb != a_idx[:, None]) & (nb != b_idx[:, None]) & (nb < xy.shape[0] - 1)
    return jnp.any(other & (jnp.sqrt(dx * dx + dy * dy) < rho), axis=1)


def _near_rows(xy, ii, jj, own, nb, rho):
    """Which points ``own`` (their segment) have one of their k-d tree neighbours ``nb``
    ``(P, k)`` (``len(xy)``: none) strictly within ρ of their segment, other than its ends:
    one compiled pass over the ``(P, k)`` lists, `_NEAR_ROWS` points a call, in float64
    (the segment test of `_near`, fused: no flat list of pairs)."""
    T = len(xy)
    P = len(own)
    out = np.zeros(P, bool)
    if not P:
        return out
    with jax.enable_x64(True):
        xyp = jnp.asarray(np.concatenate([xy, np.zeros((1, 2))]), jnp.float64)  # row T: none
        r = jnp.asarray(rho, jnp.float64)
        rows = min(_NEAR_ROWS, P)
        for s in range(0, P, rows):
            e = min(s + rows, P)
            a = np.zeros(rows, np.int64)
            b = np.zeros(rows, np.int64)
            q = np.full((rows, nb.shape[1]), T, np.int64)
            a[: e - s], b[: e - s] = ii[own[s:e]], jj[own[s:e]]
            q[: e - s] = nb[s:e]
            out[s:e] = np.asarray(_near_kernel(xyp, jnp.asarray(a), jnp.asarray(b),
                                               jnp.asarray(q), r))[: e - s]  # fmt: skip
    return out


def _near(xy, ii, jj, seg, flat, rho):
    """The segments among ``seg`` whose frame ``flat`` (not an end) is within ρ."""
    a = xy[ii[seg]]
    dist = _segment_distance(xy[flat], a, xy[jj[seg]] - a)
    return seg[(dist < rho) & (flat != ii[seg]) & (flat != jj[seg])]


@jax.jit
def _brute_chunk(xy, a_idx, b_idx):
    a, b = xy[a_idx], xy[b_idx]
    v = b - a
    L2 = jnp.maximum(jnp.sum(v * v, axis=1), jnp.finfo(xy.dtype).tiny)
    t = jnp.clip(((xy[None, :, 0] - a[:, None, 0]) * v[:, None, 0]
                  + (xy[None, :, 1] - a[:, None, 1]) * v[:, None, 1]) / L2[:, None], 0.0, 1.0)
    dx = xy[None, :, 0] - (a[:, None, 0] + t * v[:, None, 0])
    dy = xy[None, :, 1] - (a[:, None, 1] + t * v[:, None, 1])
    ids = jnp.arange(xy.shape[0])[None, :]
    end = (ids == a_idx[:, None]) | (ids == b_idx[:, None])
    return jnp.min(jnp.where(end, jnp.inf, jnp.sqrt(dx * dx + dy * dy)), axis=1)  # fmt: skip


def _brute_blocks(tree, xy, i, j, rho, step):
    """Every segment against every frame (jit, a chunk of segments at a time): cheaper
    than the points along the segments when the frames are few and the segments long.
    Segments whose nearest frame is within float32 rounding of ρ are settled again in
    float64 (`_exact_blocks`)."""
    dmin = np.zeros(len(i))
    chunk = int(max(1, min(len(i), _BRUTE_PAIRS // max(len(xy), 1))))
    xyj = jnp.asarray(xy, jnp.float32)  # float32 whatever x64 says: half the time of float64
    for s in range(0, len(i), chunk):
        a, b = i[s : s + chunk], j[s : s + chunk]
        pad = chunk - len(a)
        a = np.concatenate([a, np.zeros(pad, a.dtype)])
        b = np.concatenate([b, np.zeros(pad, b.dtype) + (1 if len(xy) > 1 else 0)])
        got = _brute_chunk(xyj, jnp.asarray(a, jnp.int32), jnp.asarray(b, jnp.int32))
        dmin[s : s + chunk - pad] = np.asarray(got, np.float64)[: chunk - pad]
    out = dmin < rho
    scale = float(np.max(np.abs(xy))) if len(xy) else 1.0
    close = np.flatnonzero(np.abs(dmin - rho) <= 2e-6 * max(rho, scale))  # float32 error
    out[close] = _exact_blocks(tree, xy, i[close], j[close], rho, step)
    return out


def segments_near_points(xy: np.ndarray, i: np.ndarray, j: np.ndarray, rho: float):
    """For each segment ``xy[i[k]] → xy[j[k]]``, whether a point of ``xy`` other than
    its two ends lies within ``rho`` of it (strictly closer). Exact.

    **Arguments:** `xy` ``(T, 2)`` float; `i`, `j` ``(E,)`` indices into it; `rho` > 0.

    **Returns:** ``(E,)`` bool."""
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, np.float64)
    i, j = np.asarray(i, np.int64), np.asarray(j, np.int64)
    tree = cKDTree(xy)
    length = np.linalg.norm(xy[j] - xy[i], axis=1)
    spacing = float(np.median(tree.query(xy, k=2)[0][:, 1])) if len(xy) > 1 else 0.0
    step = max(2.0 * rho, spacing)
    if float(len(i)) * len(xy) <= _BRUTE_PER_POINT * float(np.sum(length / step + 1.0)):
        # few frames, long segments: every segment against every frame, or, where many
        # segments leave each frame (an ε-graph's steps), by origin (`_fan_blocks`)
        if len(i) >= _FAN_FROM * len(np.unique(i)):
            return _fan_blocks(xy, i, j, rho)
        return _brute_blocks(tree, xy, i, j, rho, step)
    blocked = np.zeros(len(i), bool)
    if rho >= _SURE_FROM * spacing:  # else it blocks too few to pay for itself
        m = np.minimum(np.ceil(length / rho).astype(np.int64) + 1, _COARSE)
        blocked = _sure_blocks(tree, xy, i, j, m, rho)
    rest = np.flatnonzero(~blocked)
    blocked[rest] = _exact_blocks(tree, xy, i[rest], j[rest], rho,
                                  max(step, _EXACT_SPACINGS * spacing))  # fmt: skip
    return blocked


def _end_blocks(xy, i, j, rho):
    """Which segments have a frame (not i, not j) within ρ of an end: at most the two
    nearest other frames of each end decide (exact distances, strictly closer)."""
    from scipy.spatial import cKDTree

    k = min(3, len(xy))
    d, nb = cKDTree(xy).query(xy, k=k, distance_upper_bound=2.0 * rho)
    d, nb = d.reshape(len(xy), -1)[:, 1:], nb.reshape(len(xy), -1)[:, 1:]
    ok = nb < len(xy)
    exact = np.where(ok, np.linalg.norm(xy[np.where(ok, nb, 0)] - xy[:, None], axis=2), np.inf)
    near = np.where(exact < rho, nb, -1)  # (T, 2): up to two other frames within ρ

    def by(end, other):
        n0, n1 = near[end, 0], near[end, 1] if near.shape[1] > 1 else np.full(len(end), -1)
        return ((n0 >= 0) & (n0 != other)) | ((n1 >= 0) & (n1 != other))

    return by(i, j) | by(j, i)


def _fan_blocks(xy, i, j, rho):
    """Exactly which segments pass a frame (not i, not j) within ρ, origin by origin:
    around each origin ``a``, a frame at distance ``r > ρ`` can be within ρ of a segment
    from ``a`` only if the segment's direction is within ``asin(ρ / r)`` of the frame's
    (an angular window, found by binary search among the segments sorted by angle);
    those pairs are then measured exactly. Frames within ρ of an end block it outright
    (`_end_blocks`). Cost: the frames per origin plus the candidates, where every segment
    against every frame costs their product."""
    out = _end_blocks(xy, i, j, rho)
    order = np.argsort(i, kind="stable")
    starts = np.searchsorted(i[order], np.arange(len(xy) + 1))
    two_pi = 2.0 * np.pi
    for a in np.flatnonzero(np.diff(starts)):
        seg = order[starts[a]:starts[a + 1]]
        seg = seg[~out[seg]]
        if not len(seg):
            continue
        d = xy - xy[a]
        r = np.hypot(d[:, 0], d[:, 1])
        far = np.flatnonzero(r > rho)
        far = far[far != a]
        v = xy[j[seg]] - xy[a]
        th = np.arctan2(v[:, 1], v[:, 0])
        srt = np.argsort(th)
        ths = np.concatenate([th[srt] - two_pi, th[srt], th[srt] + two_pi])
        tq = np.arctan2(d[far, 1], d[far, 0])
        # a generous window: the exact distance below decides
        half = np.arcsin(np.minimum(1.0, rho / r[far])) * 1.001 + 1e-9
        lo = np.searchsorted(ths, tq - half, "left")
        hi = np.searchsorted(ths, tq + half, "right")
        n = hi - lo
        if not n.sum():
            continue
        q = np.repeat(far, n)
        pos = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
        k = seg[srt[pos % len(seg)]]
        keep = q != j[k]
        q, k = q[keep], k[keep]
        a_xy = np.broadcast_to(xy[a], (len(k), 2))
        hit = _segment_distance(xy[q], a_xy, xy[j[k]] - a_xy) < rho
        out[np.unique(k[hit])] = True
    return out
