"""Bridges of the ε-graphs of a threshold sweep (`bridge_parts`): per ε, the frames in the
smaller part cut off by the graph's largest bridge (see `fxspace.expression._sweep`'s
module docstring on why a bridged graph's r misleads)."""

from __future__ import annotations

import threading
import weakref

import jax
import numpy as np
from jaxtyping import Array, Bool, Float

from fxspace._validate import check_distance_matrix, checked
from fxspace.errors import FxspaceError

__all__ = ["bridge_parts"]


def _spanning_tree(P: np.ndarray) -> np.ndarray | None:
    """Parents of a minimum spanning tree of ``P`` rooted at 0 (Prim, O(n²)); ``None``
    when ``P`` is disconnected (inf entries)."""
    n = len(P)
    in_tree = np.zeros(n, bool)
    dist = np.full(n, np.inf)
    parent = np.full(n, -1)
    dist[0] = 0.0
    for _ in range(n):
        d = np.where(in_tree, np.inf, dist)
        u = int(np.argmin(d))
        if not np.isfinite(d[u]):
            return None
        in_tree[u] = True
        better = ~in_tree & (P[u] < dist)
        dist[better] = P[u][better]
        parent[better] = u
    return parent


@checked
def bridge_parts(
    pairwise: Float[Array, "n n"],
    thresholds: Float[Array, " S"],
    connected: Bool[Array, " S"] | None = None,
) -> np.ndarray:
    """Per ε, the frames in the smaller part cut off by the ε-graph's largest bridge.

    Bridges of a connected graph are edges of every spanning tree, so only the ``n − 1``
    edges of one minimum spanning tree are candidates: the tree edge above node ``v`` is
    a bridge of the ε-graph iff exactly one graph edge leaves ``v``'s subtree. With the
    nodes in the tree's depth-first order every subtree is a contiguous block, so the
    edges leaving each of them are two rectangle sums of the 2-D prefix sum of the
    adjacency matrix: O(n²) per ε, on the host. Bridges only disappear as ε grows, so
    the scan stops at the first ε without one.

    **Arguments:** ``pairwise`` ``(n, n)`` state distances; ``thresholds`` ``(S,)``;
    ``connected`` ``(S,)`` (computed when ``None``): disconnected ε get 0.

    **Returns:** ``(S,)`` int32, 0 where no edge is a bridge.
    """
    if np.ndim(pairwise) != 2 or np.shape(pairwise)[0] != np.shape(pairwise)[1]:
        raise FxspaceError(
            f"pairwise must be a square (n, n) matrix, got shape {np.shape(pairwise)}")
    check_distance_matrix(pairwise, "pairwise", allow_inf=True)  # once per JAX array
    th = np.asarray(thresholds, np.float64).reshape(-1)
    if np.isnan(th).any():
        raise FxspaceError("thresholds must be numbers (ε), got NaN")
    if connected is not None and np.asarray(connected).reshape(-1).shape != th.shape:
        raise FxspaceError(
            f"connected must hold one flag per threshold ({th.shape[0]}), got shape "
            f"{np.shape(connected)}"
        )
    n = int(np.shape(pairwise)[0])
    out = np.zeros(th.shape, np.int32)
    if n < 3:
        return out
    held = _held(pairwise)  # a sweep's chunks ask for the same JAX array, one ε at a time
    tree = held[1] if held is not None else _tree(np.asarray(pairwise, np.float64))
    if held is None and isinstance(pairwise, jax.Array):
        held = _hold(pairwise, tree)
    if tree is None:
        return out
    Pp, lo, hi, part, t_conn = tree
    conn = th >= t_conn if connected is None else np.asarray(connected, bool).reshape(-1)
    for k in np.argsort(th):
        if not conn[k]:
            continue
        if held is not None and th[k] >= held[2][0]:
            break  # an ε at or below this one had no bridge: none here either
        A = (Pp <= th[k]).astype(np.int32)
        np.fill_diagonal(A, 0)
        C = np.zeros((n + 1, n + 1), np.int64)
        C[1:, 1:] = A.cumsum(0).cumsum(1)

        # edges from the block [lo, hi) to the columns before it and after it
        leaving = (C[hi, lo] - C[lo, lo] - C[hi, 0] + C[lo, 0]) + (
            C[hi, n] - C[lo, n] - C[hi, hi] + C[lo, hi]
        )
        bridged = part[leaving == 1]
        if not bridged.size:
            if held is not None:
                with _LOCK:
                    held[2][0] = min(held[2][0], float(th[k]))
            break  # no bridge here, none at any larger ε
        out[k] = int(bridged.max())
    return out


def _tree(P: np.ndarray):
    """``(Pp, lo, hi, part, t_conn)``: ``P`` in a minimum spanning tree's depth-first
    order, each tree edge's subtree block ``[lo, hi)`` and smaller side, and the
    connecting threshold; ``None`` when ``P`` is disconnected."""
    n = len(P)
    parent = _spanning_tree(np.where(np.isfinite(P), P, np.inf))
    if parent is None:
        return None
    t_conn = max(float(P[v, parent[v]]) for v in range(1, n))
    kids: list[list[int]] = [[] for _ in range(n)]
    for v in range(1, n):
        kids[parent[v]].append(v)
    order, stack = [], [0]
    while stack:
        v = stack.pop()
        order.append(v)
        stack.extend(reversed(kids[v]))
    order_a = np.asarray(order)
    size = np.ones(n, np.int64)
    for v in order[::-1]:
        if parent[v] >= 0:
            size[parent[v]] += size[v]
    tin = np.empty(n, np.int64)
    tin[order_a] = np.arange(n)
    lo = tin[order_a[1:]]
    sz = size[order_a[1:]]
    return P[np.ix_(order_a, order_a)], lo, lo + sz, np.minimum(sz, n - sz), t_conn


# The tree of the last pairwise JAX arrays asked about (immutable: held by a weak reference,
# so an id reused by another array is never taken for it), with the smallest ε known to
# have no bridge: a sweep cut into one-ε chunks builds the tree once, and skips every ε
# above the first bridge-free one, as one call over all thresholds does.
_TREES: dict[int, tuple] = {}
_LOCK = threading.Lock()


def _held(pairwise):
    with _LOCK:
        got = _TREES.get(id(pairwise))
    if got is None or got[0]() is not pairwise:
        return None
    return got


def _hold(pairwise, tree):
    got = (weakref.ref(pairwise), tree, [np.inf])
    with _LOCK:
        for k in [k for k, v in _TREES.items() if v[0]() is None]:
            del _TREES[k]
        while len(_TREES) >= 2:
            del _TREES[next(iter(_TREES))]
        _TREES[id(pairwise)] = got
    return got
