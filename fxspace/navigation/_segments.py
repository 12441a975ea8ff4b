"""Which 2-D segments pass within ρ of another point, exactly, at 10⁵–10⁶ segments.

The links of the level where every frame is a centre (Kim & Jung §4.2 at its finest)
are the graph's steps whose segment passes no other frame within ρ. Segments are long
against ρ (on a k-NN graph of 10⁵ frames the median step is ~200 ρ), so a test per
segment against every frame near its midpoint costs O(T²) overall. Here:

1. **Sure blocks, coarse to fine.** Points on each segment, 8 then 32 then one per ρ;
   a frame (other than the segment's ends) within ρ of a point on the segment is within
   ρ of the segment, so the segment is blocked. Each round keeps only the segments no
   earlier round blocked; almost every blocked segment goes in the first round.
2. **Exact, for the rest.** Points every ``s`` along the segment (ends included) and
   every frame within ``sqrt(ρ² + (s/2)²)`` of one of them: a frame within ρ of the
   segment has its foot within ``s/2`` of a point, so it is among them; their exact
   segment distances decide.

Both passes use one k-d tree over the frames (scipy ``cKDTree``).
"""

from __future__ import annotations

import numpy as np

_ROUNDS = (8, 32)  # points per segment in the coarse rounds; then one per ρ
_BATCH = 1 << 21  # sample points per k-d tree call


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
        d, nb = tree.query(pts, k=min(3, len(xy)), distance_upper_bound=rho)
        d, nb = d.reshape(len(pts), -1), nb.reshape(len(pts), -1)
        hit = (d < rho) & (nb != ii[own][:, None]) & (nb != jj[own][:, None])
        out[sl.start + np.unique(own[hit.any(axis=1)])] = True
    return out


def _exact_blocks(tree, xy, i, j, rho):
    """Exactly which segments pass a frame (not i, not j) within ρ (module docstring)."""
    out = np.zeros(len(i), bool)
    if not len(i):
        return out
    step = 2.0 * rho
    reach = float(np.hypot(rho, 0.5 * step))
    length = np.linalg.norm(xy[j] - xy[i], axis=1)
    m = np.ceil(length / step).astype(np.int64) + 1
    for sl in _batches(4 * m):  # the balls hold a few frames each
        ii, jj = i[sl], j[sl]
        own, pts = _samples(xy[ii], xy[jj], m[sl])
        lists = tree.query_ball_point(pts, reach, return_sorted=False)
        n = np.fromiter((len(x) for x in lists), np.int64, len(lists))
        flat = np.fromiter((k for x in lists for k in x), np.int64, int(n.sum()))
        seg = own[np.repeat(np.arange(len(pts)), n)]
        a = xy[ii[seg]]
        d = _segment_distance(xy[flat], a, xy[jj[seg]] - a)
        hit = (d < rho) & (flat != ii[seg]) & (flat != jj[seg])
        out[sl.start + np.unique(seg[hit])] = True
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
    blocked = np.zeros(len(i), bool)
    length = np.linalg.norm(xy[j] - xy[i], axis=1)
    fine = np.ceil(length / rho).astype(np.int64) + 1
    for pts in (*_ROUNDS, None):
        rest = np.flatnonzero(~blocked)
        m = fine[rest] if pts is None else np.minimum(fine[rest], pts)
        blocked[rest] = _sure_blocks(tree, xy, i[rest], j[rest], m, rho)
    rest = np.flatnonzero(~blocked)
    blocked[rest] = _exact_blocks(tree, xy, i[rest], j[rest], rho)
    return blocked
