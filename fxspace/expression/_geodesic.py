"""Neighbourhood graph and geodesic distances (Kim & Jung, §3.2; Floyd 1962).

The ε-graph links two frames when their state distance is at most ε. Geodesic
distances are the all-pairs shortest paths of that graph, computed with the min-plus
Floyd–Warshall recurrence

    D⁽ᵏ⁾[i, j] = min(D⁽ᵏ⁻¹⁾[i, j], D⁽ᵏ⁻¹⁾[i, k] + D⁽ᵏ⁻¹⁾[k, j]),

either one pivot at a time (``lax.scan``, memory-bound past ~1000 frames) or in the
three-phase blocked form (Venkataraman et al. 2003): close the diagonal tile, update its
row and column panels, then update the whole matrix with one min-plus product of the
panels. Both are O(T³) work and branch-free, so a whole threshold sweep is one ``vmap``.
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import as_float_array, check_choice, check_int, check_scalar, checked
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression._floyd_fold import _floyd_folded, _pick_fold_block
from fxspace.expression._floyd_kernels import (
    _floyd_blocked,
    _floyd_scan,
    _floyd_sharded,
    _pick_block,
)
from fxspace.expression._paths import geodesic_lengths, geodesic_steps, geodesic_toward
from fxspace.expression._sparse import NeighbourGraph
from fxspace.expression._sparse import sparse_shortest_path as _graph_shortest_path

__all__ = [
    "Geodesics",
    "epsilon_graph",
    "floyd_warshall",
    "geodesic_distances",
    "next_hops",
    "shortest_path",
    "connected_components",
    "connecting_threshold",
    "check_connected",
]


_BLOCKED_FROM = 256
_SHARDED_FROM = 1024  # "auto" shards Floyd's rows over the local devices from here on


FloydMethod = Literal["auto", "scan", "blocked", "sharded"]


class Geodesics(NamedTuple):
    """All-pairs shortest paths.

    - `distances`: ``(T, T)`` geodesic distances, ``inf`` between unreachable frames.
    - `next_hop`: ``(T, T)`` int32; ``next_hop[i, j]`` is the frame after ``i`` on a
      shortest path to ``j`` (``next_hop[i, i] = i``; ``-1`` when ``j`` is unreachable).
    """

    distances: Float[Array, "n n"]
    next_hop: Int[Array, "n n"]

    # the paths interface of navigation (fxspace.expression._paths.Paths)
    @property
    def num_frames(self) -> int:
        return int(self.distances.shape[0])

    def path(self, i: int, j: int, limit: float | None = None) -> np.ndarray:
        """Frames of a shortest path i → j (the next hops; `limit` is not needed)."""
        return shortest_path(self, i, j)

    def lengths(self, i, j) -> np.ndarray:
        """Geodesic lengths of the pairs ``(i[p], j[p])``."""
        return geodesic_lengths(self, i, j)

    def toward(self, targets) -> tuple[np.ndarray, np.ndarray]:
        """``(dist, hop)`` ``(k, T)``: each frame's distance to ``targets[r]`` and its next
        frame on a shortest path there (the target itself at it, -1 when unreachable)."""
        return geodesic_toward(self, targets)

    def steps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(i, j, length)`` of the pairs i < j whose shortest path is the direct step."""
        return geodesic_steps(self)


def _check_square(x, name: str) -> Array:
    """``x`` as a non-empty square ``(n, n)`` float array (NaN/inf kept), else a `FxspaceError`."""
    a = as_float_array(x, name, ndim=2, finite="allow")
    if a.shape[0] != a.shape[1]:
        raise FxspaceError(f"{name} must be a square (n, n) matrix, got shape {a.shape}")
    return a


def epsilon_graph(pairwise: Float[Array, "n n"], threshold: float | Array) -> Float[Array, "n n"]:
    """ε-neighbour graph: ``W[i,j] = P[i,j]`` if ``P[i,j] ≤ ε`` else ``inf``; ``W[i,i] = 0``."""
    P = as_float_array(pairwise, "pairwise", ndim=2, finite="allow")
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise FxspaceError(f"pairwise must be a square (n, n) matrix, got shape {P.shape}")
    if not isinstance(threshold, jax.core.Tracer) and np.ndim(threshold) == 0:
        threshold = check_scalar(threshold, "threshold")
    elif not isinstance(threshold, jax.core.Tracer):
        threshold = as_float_array(threshold, "threshold", min_frames=0)
        try:
            ok = np.broadcast_shapes(threshold.shape, P.shape) == P.shape
        except ValueError:
            ok = False
        if not ok:
            raise FxspaceError(f"threshold must be a scalar (or broadcast to {P.shape})")
    W = jnp.where(P <= threshold, P, jnp.inf)
    return jnp.where(jnp.eye(P.shape[0], dtype=bool), jnp.zeros((), P.dtype), W)


_FOLDED_OVER_SHARDED_UP_TO = 2  # devices: folded on one beat sharded over 2 (2-core CPU)


def _is_symmetric(W: Array, symmetric: bool | None) -> bool:
    """``symmetric`` if given, else whether a concrete ``W`` equals its transpose (a traced
    one, under ``jit``/``vmap``/``grad``, counts as directed: pass ``symmetric=True``)."""
    if symmetric is not None:
        return bool(symmetric)
    if isinstance(W, jax.core.Tracer):
        return False
    return bool(_equals_transpose(W))


@jax.jit
def _equals_transpose(W: Array) -> Array:
    return jnp.all(W == W.T)


@checked
def floyd_warshall(
    graph: Float[Array, "n n"],
    method: FloydMethod = "auto",
    block: int | None = None,
    symmetric: bool | None = None,
) -> Float[Array, "n n"]:
    """Geodesic distances only (no next-hop matrix): min-plus Floyd–Warshall.

    **Arguments:**
    - `graph`: ``(n, n)`` edge weights, ``inf`` for no edge, 0 on the diagonal.
    - `method`: ``"scan"`` (one pivot per ``lax.scan`` step), ``"blocked"`` (three-phase
      tiled, cache-friendly), ``"sharded"`` (blocked, rows split over all local devices,
      the result gathered to every device) or ``"auto"`` (scan below 256 vertices; from
      there blocked — folded for an undirected graph while there are at most 2 local
      devices — and sharded from 1024 vertices on over several devices otherwise).
    - `block`: tile size of the blocked variants (default: 40–80, or 80–128 folded,
      chosen to pad least).
    - `symmetric`: whether ``graph`` is undirected (``graph == graph.T``). Then the
      blocked method runs *folded* (`_floyd_folded`: the upper tiles only, half the
      work) and reads only the upper triangle. ``None`` (default): checked on a concrete
      graph (an O(n²) comparison); a traced one (inside ``jit``/``vmap``/``grad``) is
      taken as directed — pass ``True`` there to get the folded kernel.

    O(n³) work (n³/2 folded), O(n²) memory; jit/vmap/grad compatible (the gradient of a
    geodesic distance is the indicator of the edges on its shortest path; folded, it is
    all on the upper triangle). A sharded result is gathered to the first local device
    when called outside ``jit`` (so what follows runs once, unpartitioned), and
    replicated on every device under ``jit``.
    """
    _check_square(graph, "graph")
    check_choice(method, "method", ("auto", "scan", "blocked", "sharded"))
    if block is not None:
        block = check_int(block, "block", low=1)
    sym = _is_symmetric(graph, symmetric)
    D = _floyd_jit(graph, method, block, sym)
    if not isinstance(D, jax.core.Tracer) and len(D.sharding.device_set) > 1:
        D = jax.device_put(D, jax.local_devices()[0])
    return D


@partial(jax.jit, static_argnames=("method", "block", "symmetric"))
def _floyd_jit(graph: Array, method: str, block: int | None, symmetric: bool = False) -> Array:
    W = jnp.asarray(graph)
    n, nd = W.shape[0], jax.local_device_count()
    if method == "auto":
        method = "blocked" if n >= _BLOCKED_FROM else "scan"
        if n >= _SHARDED_FROM and nd > 1 and not (symmetric and nd <= _FOLDED_OVER_SHARDED_UP_TO):
            method = "sharded"
    if method == "scan":
        return _floyd_scan(W)
    if method == "blocked" and symmetric:
        return _floyd_folded(W, block or _pick_fold_block(n))
    if method == "blocked":
        return _floyd_blocked(W, block or _pick_block(n, 1))
    if method == "sharded":
        return _floyd_sharded(W, block or _pick_block(n, nd))
    raise FxspaceError(f"method must be 'auto', 'scan', 'blocked' or 'sharded', got {method!r}")


_HOP_GROUP = 16  # neighbours per pass of the next-hop search (fused, in registers)


@checked
@partial(jax.jit, static_argnames=("max_degree", "chunk"))
def next_hops(
    graph: Float[Array, "n n"],
    distances: Float[Array, "n n"],
    max_degree: int | None = None,
    chunk: int = 16,
) -> Int[Array, "n n"]:
    """Next-hop matrix from geodesic distances: ``nxt[i, j] = argmin_k W[i,k] + D[k,j]``.

    The first step of a shortest path ``i → j`` is a neighbour ``k`` of ``i`` attaining the
    Bellman equation ``D[i,j] = min_k W[i,k] + D[k,j]``; only neighbours strictly closer to
    ``j`` (``D[k,j] < D[i,j]``) are candidates, so every hop gets closer to ``j`` and no
    walk can cycle, float32 ties and zero-weight edges (repeated frames) included; a
    zero-distance pair is one hop. Rows go ``chunk`` consecutive vertices at a time: a
    block streams once over the union of its rows' neighbours (ascending, ties to the
    smallest vertex), ``16`` neighbour rows of ``D`` fused per pass, keeping the running
    minimum and its index over all ``j`` for every row of the block. The work is
    O(n · Σ_blocks |union|) — n·E (E edges, the cost of ``n`` Dijkstra runs) times the
    union's excess over a row's degree, small when consecutive vertices share neighbours,
    as consecutive frames of a capture do (1.4 on AnimFace; at most ``chunk``). Found from
    the final distances, the hops are valid for any Floyd variant.

    **Arguments:**
    - `graph`: ``(n, n)`` edge weights (``inf`` = no edge), directed or not.
    - `distances`: its geodesic distances (`floyd_warshall`).
    - `max_degree`: keep only each vertex's ``max_degree`` nearest neighbours (``None``:
      all; fewer may give no hop, ``-1``, where every shortest path needs a dropped edge).
    - `chunk`: consecutive vertices per block (static).

    **Returns:** ``(n, n)`` int32 next hops, ``i`` on the diagonal, ``-1`` where ``j`` is
    not reachable from ``i``.
    """
    W = _check_square(graph, "graph")
    D = _check_square(distances, "distances")
    if D.shape != W.shape or chunk < 1 or (max_degree is not None and max_degree < 1):
        raise FxspaceError(
            f"next_hops needs distances of the graph's shape {W.shape} (got {D.shape}), "
            f"chunk >= 1 (got {chunk}) and max_degree >= 1 or None (got {max_degree})"
        )
    n = W.shape[0]
    D = D.astype(jnp.result_type(W.dtype, D.dtype))
    eye = jnp.eye(n, dtype=bool)
    Woff = jnp.where(eye, jnp.inf, W).astype(D.dtype)
    if max_degree is not None and max_degree < n - 1:
        near = jnp.argsort(Woff, axis=1)[:, :max_degree]
        keep = jnp.zeros((n, n), bool).at[jnp.arange(n)[:, None], near].set(True)
        Woff = jnp.where(keep, Woff, jnp.inf)
    c = min(chunk, n)
    pad = (-n) % c
    Wb = jnp.concatenate([Woff, jnp.full((pad, n), jnp.inf, D.dtype)]).reshape(-1, c, n)
    Db = jnp.concatenate([D, jnp.zeros((pad, n), D.dtype)]).reshape(-1, c, n)
    union = jnp.any(jnp.isfinite(Wb), axis=1)  # (blocks, n)
    size = jnp.sum(union, axis=1, dtype=jnp.int32)
    nbrs = jnp.argsort(~union, axis=1, stable=True).astype(jnp.int32)  # the union first
    g = _HOP_GROUP

    def block(args):
        w, d_own, nbr, u = args  # (c, n), (c, n), (n,), ()

        def body(t, state):
            best, arg = state
            for s in range(g):
                q = jnp.minimum(t * g + s, n - 1)
                k = nbr[q]
                wk = jnp.where(t * g + s < u, jax.lax.dynamic_slice_in_dim(w, k, 1, 1), jnp.inf)
                dk = jax.lax.dynamic_slice_in_dim(D, k, 1, 0)  # (1, n)
                val = jnp.where(dk < d_own, wk + dk, jnp.inf)
                better = val < best
                best = jnp.where(better, val, best)
                arg = jnp.where(better, k, arg)
            return best, arg

        init = (jnp.full((c, n), jnp.inf, D.dtype), jnp.full((c, n), -1, jnp.int32))
        return jax.lax.fori_loop(0, (u + g - 1) // g, body, init)[1]

    nxt = jax.lax.map(block, (Wb, Db, nbrs, size)).reshape(-1, n)[:n]
    j = jnp.arange(n, dtype=jnp.int32)
    nxt = jnp.where((D == 0) & jnp.isfinite(Woff), j[None, :], nxt)  # repeated frames
    nxt = jnp.where(jnp.isfinite(D), nxt, -1)
    return jnp.where(eye, j[:, None], nxt)


@checked
def geodesic_distances(
    graph: Float[Array, "n n"],
    method: FloydMethod = "auto",
    block: int | None = None,
    symmetric: bool | None = None,
) -> Geodesics:
    """All-pairs geodesic distances and the next-hop matrix that rebuilds paths.

    **Arguments:**
    - `graph`: ``(n, n)`` symmetric or directed edge weights (``inf`` = no edge, 0 diagonal),
      e.g. from `epsilon_graph`.
    - `method`, `block`, `symmetric`: see `floyd_warshall` (an undirected graph runs the
      folded Floyd, half the work).

    **Returns:** `Geodesics`. Unreachable pairs keep ``inf`` distance and next hop
    ``-1`` — check with `check_connected` before embedding. The next-hop matrix is
    found from the distances by `next_hops` (the Bellman equation over each
    vertex's neighbours, every hop strictly closer to the target), which stays valid under
    float32 ties — carrying it through the Floyd recurrence does not (rounding ties made
    next-hop cycles on real data). O(n³) for the distances plus O(n·E) for the hops (E
    edges); jit/vmap compatible; ``jax.grad`` flows through the distances.
    """
    W = jnp.asarray(graph)
    if W.ndim != 2 or W.shape[0] != W.shape[1]:
        raise FxspaceError(f"graph must be a square (n, n) matrix, got shape {W.shape}")
    D = floyd_warshall(W, method=method, block=block, symmetric=symmetric)
    nxt = next_hops(W, jax.lax.stop_gradient(D))
    return Geodesics(D, nxt)


@checked
def shortest_path(geo: Geodesics | NeighbourGraph, i: int, j: int) -> np.ndarray:
    """Frames of a shortest path from ``i`` to ``j`` inclusive: a host-side walk of the
    ``Geodesics``' next hops, or on a `NeighbourGraph` one single-source Dijkstra with
    predecessors (O(E log T), stopped once ``j`` is settled: no ``T × T`` matrix).

    **Raises:** `DisconnectedGraphError` when ``j`` is unreachable from ``i``."""
    if isinstance(geo, NeighbourGraph):
        return _graph_shortest_path(geo, i, j)
    if not hasattr(geo, "next_hop"):
        raise FxspaceError(
            f"geo must be the Geodesics of geodesic_distances or a NeighbourGraph, got "
            f"{type(geo).__name__}"
        )
    nxt = np.asarray(geo.next_hop)
    n = nxt.shape[0]
    for name, v in (("i", i), ("j", j)):
        if not (0 <= int(v) < n):
            raise FxspaceError(f"{name}={v} is out of range for a graph of {n} frames")
    i, j = int(i), int(j)
    if nxt[i, j] < 0:
        raise DisconnectedGraphError(
            f"frame {j} is not reachable from frame {i}: the graph is disconnected at this "
            "threshold; raise it (see connecting_threshold)"
        )
    path = [i]
    while path[-1] != j:
        path.append(int(nxt[path[-1], j]))
        if len(path) > n:
            raise FxspaceError(f"next-hop matrix has a cycle on the way {i} → {j}")
    return np.asarray(path, dtype=np.int64)


@checked
@jax.jit
def connected_components(graph: Float[Array, "n n"]) -> tuple[Array, Int[Array, " n"]]:
    """Connected components of an undirected graph (finite off-diagonal = edge).

    Label propagation (each vertex takes the smallest label among its neighbours) until
    nothing changes; returns ``(n_components, labels)`` with labels the smallest vertex
    index of each component. O(n² · diameter).
    """
    A = jnp.isfinite(_check_square(graph, "graph"))
    A = A | A.T
    n = A.shape[0]
    big = jnp.int32(n)

    def body(state):
        lab, _ = state
        new = jnp.min(jnp.where(A, lab[None, :], big), axis=1)
        new = jnp.minimum(new, lab)
        return new, jnp.any(new != lab)

    lab, _ = jax.lax.while_loop(lambda s: s[1], body, (jnp.arange(n, dtype=jnp.int32), True))
    n_comp = jnp.sum(lab == jnp.arange(n))
    return n_comp, lab


@checked
@jax.jit
def connecting_threshold(pairwise: Float[Array, "n n"]) -> Array:
    """Smallest ε for which the ε-graph of ``pairwise`` is connected.

    It is the largest edge of a minimum spanning tree (the minimax path bound), found
    with Prim's algorithm in O(n²).
    """
    P = _check_square(pairwise, "pairwise")
    n = P.shape[0]
    in_tree = jnp.zeros(n, bool).at[0].set(True)
    best = P[0]

    def body(_, state):
        in_tree, best, worst = state
        cand = jnp.where(in_tree, jnp.inf, best)
        k = jnp.argmin(cand)
        worst = jnp.maximum(worst, cand[k])
        in_tree = in_tree.at[k].set(True)
        best = jnp.minimum(best, P[k])
        return in_tree, best, worst

    _, _, worst = jax.lax.fori_loop(1, n, body, (in_tree, best, jnp.zeros((), P.dtype)))
    return worst


def check_connected(graph: Array, pairwise: Array | None = None) -> None:
    """Raise `DisconnectedGraphError` naming the components and the fix.

    A connected graph is recognised in O(n²) (its minimum spanning tree by Prim,
    `connecting_threshold`, has no infinite edge); only a disconnected one is labelled
    (`connected_components`) for the message."""
    G = _check_square(graph, "graph")
    if not isinstance(G, jax.core.Tracer) and bool(
        jnp.isfinite(connecting_threshold(jnp.minimum(G, G.T)))
    ):
        return
    n_comp, labels = connected_components(graph)
    n_comp = int(n_comp)
    if n_comp == 1:
        return
    sizes = np.bincount(np.unique(np.asarray(labels), return_inverse=True)[1])
    msg = (
        f"the neighbourhood graph has {n_comp} connected components "
        f"(sizes {sorted(sizes.tolist(), reverse=True)[:10]})"
    )
    if pairwise is not None:
        msg += (
            f"; the smallest threshold that connects it is "
            f"{float(connecting_threshold(pairwise)):.6g}"
        )
    raise DisconnectedGraphError(msg + ": raise the threshold or drop the isolated frames")
