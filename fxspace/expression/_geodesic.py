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

_BLOCK = 64


def _pick_block(n: int, parts: int) -> int:
    """Tile size in 40…80 (multiples of 8) that pads ``n`` least for ``parts`` row slabs;
    ties go to the size nearest 64 (padding is pure waste in an O(n³) loop)."""
    cands = range(40, 81, 8)
    return min(cands, key=lambda b: (-(-n // (b * parts)) * b * parts, abs(b - _BLOCK), b))


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
        from fxspace.expression._paths import geodesic_lengths

        return geodesic_lengths(self, i, j)

    def toward(self, targets) -> tuple[np.ndarray, np.ndarray]:
        """``(dist, hop)`` ``(k, T)``: each frame's distance to ``targets[r]`` and its next
        frame on a shortest path there (the target itself at it, -1 when unreachable)."""
        from fxspace.expression._paths import geodesic_toward

        return geodesic_toward(self, targets)

    def steps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(i, j, length)`` of the pairs i < j whose shortest path is the direct step."""
        from fxspace.expression._paths import geodesic_steps

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


def _minplus(A: Array, B: Array) -> Array:
    """Min-plus product ``C[i,j] = min_k A[i,k] + B[k,j]``.

    XLA fuses the broadcast add into one reduction, vectorised along ``j`` (reducing
    over the middle axis measured ~25 % less CPU time than over the last one).
    """
    return jnp.min(A[:, :, None] + B[None, :, :], axis=1)


_COL_TILE = 512  # columns of a D tile kept in cache while a row block streams its pivots
_TILE_FROM_BYTES = 1 << 20  # row blocks larger than this (about half an L2) are tiled


def _col_tiles(m: int, rb: int, itemsize: int) -> int:
    """Column tiles of the phase-3 update: 1 (whole row blocks) while an ``rb × m`` row
    block fits `_TILE_FROM_BYTES`, else tiles of ≈ `_COL_TILE` columns."""
    return 1 if rb * m * itemsize <= _TILE_FROM_BYTES else max(1, round(m / _COL_TILE))


def _col_pad(m: int, rb: int, itemsize: int) -> int:
    """Padded column count of the blocked Floyd matrix, so that `_minplus_update` can cut
    it into `_col_tiles` tiles whose widths are multiples of 8 (padding columns are inf)."""
    nc = _col_tiles(m, rb, itemsize)
    return m if nc == 1 else nc * (-(-m // (8 * nc)) * 8)


def _minplus_update(D: Array, C: Array, R: Array, rb: int) -> Array:
    """``min(D, C ⊗ R)`` for a tall ``D`` (rows a multiple of ``rb``), cache-friendly.

    Streams the ``k`` index over blocks of ``rb`` rows, so each row block of ``D`` stays
    in cache while the pivot rows ``R[k]`` are broadcast-added (eight pivots fused per
    pass) — plain vector code, ~20–30 % less CPU time than one fused ``(n, b, n)``
    reduction. Past ~1 MiB a row block no longer stays in cache: it is then cut into
    ``rb × cw`` tiles (``cw`` ≈ `_COL_TILE` columns) that the pivots stream through.
    """
    n, m = D.shape
    b = C.shape[1]
    nc = _col_tiles(m, rb, D.dtype.itemsize)
    while m % nc or (m // nc) % 8:
        nc -= 1
    cw = m // nc

    def tile(c, d, r):
        def body(k, d):
            return jnp.minimum(d, c[:, k, None] + r[k][None, :])

        return jax.lax.fori_loop(0, b, body, d, unroll=8)

    Cb = C.reshape(n // rb, rb, b)
    if nc == 1:
        out = jax.lax.map(lambda a: tile(a[1], a[0], R), (D.reshape(n // rb, rb, m), Cb))
        return out.reshape(n, m)
    Dt = D.reshape(n // rb, rb, nc, cw).transpose(0, 2, 1, 3)  # (row blocks, tiles, rb, cw)
    Rt = R.reshape(b, nc, cw).transpose(1, 0, 2)  # (tiles, b, cw)

    def row_block(args):
        d_row, c = args
        return jax.lax.map(lambda a: tile(c, a[0], a[1]), (d_row, Rt))

    out = jax.lax.map(row_block, (Dt, Cb))
    return out.transpose(0, 2, 1, 3).reshape(n, m)


def _floyd_scan(W: Array) -> Array:
    def step(D, k):
        row = jax.lax.dynamic_slice_in_dim(D, k, 1, axis=0)
        col = jax.lax.dynamic_slice_in_dim(D, k, 1, axis=1)
        return jnp.minimum(D, col + row), None

    D, _ = jax.lax.scan(step, W, jnp.arange(W.shape[0]))
    return D


def _floyd_blocked(W: Array, block: int) -> Array:
    n = W.shape[0]
    nb = -(-n // block)
    m = nb * block
    mc = _col_pad(m, block, W.dtype.itemsize)  # columns past m: inf, never on a path
    D = jnp.full((m, mc), jnp.inf, W.dtype).at[:n, :n].set(W)
    idx = jnp.arange(n, m)
    D = D.at[idx, idx].set(0)

    def phase(kb, D):
        s = kb * block
        dkk = _floyd_scan(jax.lax.dynamic_slice(D, (s, s), (block, block)))
        R = jax.lax.dynamic_slice(D, (s, 0), (block, mc))
        C = jax.lax.dynamic_slice(D, (0, s), (m, block))
        R = jnp.minimum(R, _minplus(dkk, R))
        C = jnp.minimum(C, _minplus(C, dkk))
        return _minplus_update(D, C, R, block)

    D = jax.lax.fori_loop(0, nb, phase, D)
    return D[:n, :n]


def _floyd_sharded(W: Array, block: int) -> Array:
    """Blocked Floyd with the rows split across all local devices (``shard_map``).

    Each device owns a slab of rows; per pivot block the ``block`` pivot rows are
    broadcast (a masked ``psum``), every device closes the diagonal tile and updates the
    row panel redundantly, then updates its own slab. On a CPU started with
    ``--xla_force_host_platform_device_count=N`` (the ``fxspace`` command does this) each
    device is one core, so the O(n³) work runs on all cores. The slabs are gathered (made
    replicated) as soon as the pivot loop ends: XLA:CPU aborts a collective whose
    participants arrive more than 40 s apart, which partitioned downstream ops caused.
    """
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as Ps

    devs = jax.local_devices()
    nd = len(devs)
    n = W.shape[0]
    unit = block * nd
    m = -(-n // unit) * unit
    rows = m // nd
    mc = _col_pad(m, block, W.dtype.itemsize)  # columns past m: inf, never on a path
    D = jnp.full((m, mc), jnp.inf, W.dtype).at[:n, :n].set(W)
    idx = jnp.arange(n, m)
    D = D.at[idx, idx].set(0)
    mesh = Mesh(np.array(devs), ("rows",))

    def slab(Dl):
        me = jax.lax.axis_index("rows")

        def phase(kb, Dl):
            s = kb * block
            owner = s // rows
            mine = jax.lax.dynamic_slice(Dl, (s - owner * rows, 0), (block, mc))
            R = jax.lax.psum(jnp.where(me == owner, mine, jnp.zeros_like(mine)), "rows")
            dkk = _floyd_scan(jax.lax.dynamic_slice(R, (0, s), (block, block)))
            R = jnp.minimum(R, _minplus(dkk, R))
            C = jax.lax.dynamic_slice(Dl, (0, s), (rows, block))
            C = jnp.minimum(C, _minplus(C, dkk))
            return _minplus_update(Dl, C, R, block)

        return jax.lax.fori_loop(0, m // block, phase, Dl)

    D = jax.shard_map(
        slab, mesh=mesh, in_specs=Ps("rows", None), out_specs=Ps("rows", None), check_vma=False
    )(D)
    # gather the slabs right away (every device leaves the pivot loop together), so no
    # downstream op is partitioned into collectives that could arrive far apart
    D = jax.lax.with_sharding_constraint(D, NamedSharding(mesh, Ps()))
    return D[:n, :n]


_FOLD_BLOCKS = range(80, 129, 8)  # tile sizes of the folded (undirected) Floyd
_FOLD_GROUP_BYTES = 1 << 20  # a strip's column group stays in L2 while its pivots stream


def _pick_fold_block(n: int) -> int:
    """Tile size in 80…128 (multiples of 8) that pads ``n`` least to an even number of tiles;
    ties go to the size nearest 96 (measured fastest on AnimFace, 2461 frames)."""
    return min(_FOLD_BLOCKS, key=lambda b: (-(-n // (2 * b)) * 2 * b, abs(b - 96), b))


def _fold_layout(nb: int, b: int, itemsize: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Static tables of the folded upper triangle of ``nb × nb`` tiles (``nb`` even).

    Pair ``p < nb/2`` holds the upper tiles of tile row ``p`` (columns ``p … nb-1``) then
    those of tile row ``q = nb-1-p`` (columns ``q … nb-1``): ``nb + 1`` tiles in all for
    every pair, a rectangle. Returns the tile row and column of every slot
    ``(nb/2, slots)`` (slots past ``nb + 1`` pad the strip to ``groups × per_group``) and
    the group count and slots per group (a group is ``b × per_group·b``, ≤ 1 MiB).
    """
    half, slots = nb // 2, nb + 1
    per = max(1, min(slots, _FOLD_GROUP_BYTES // (b * b * itemsize)))
    groups = -(-slots // per)
    per = -(-slots // groups)
    rows = np.zeros((half, groups * per), np.int32)
    cols = np.zeros((half, groups * per), np.int32)
    for p in range(half):
        q = nb - 1 - p
        for t in range(slots):
            rows[p, t], cols[p, t] = (p, p + t) if t < nb - p else (q, q + t - (nb - p))
    return rows, cols, groups, per


def _fold_slot(i: Array, j: Array, nb: int) -> tuple[Array, Array]:
    """Pair and slot of the upper tile ``(i, j)``, ``i ≤ j`` (inverse of `_fold_layout`)."""
    low = i < nb // 2
    p = jnp.where(low, i, nb - 1 - i)
    return p, jnp.where(low, j - i, nb - p + j - i)


def _floyd_folded(W: Array, block: int, unroll: int = 4) -> Array:
    """Blocked Floyd on an undirected graph, storing and updating only the upper tiles.

    Every ``D⁽ᵏ⁾`` of a symmetric ``W`` is symmetric (a sum is commutative in floating
    point too), so the column panel of pivot block ``k`` is its row panel transposed and
    phase 3 need only touch the tiles ``(I, J)``, ``I ≤ J``: half the O(n³) work. The
    upper triangle is kept *folded*: tile row ``p`` and tile row ``nb-1-p`` share one
    ``b × (nb+1)·b`` strip (`_fold_layout`), so phase 3 is a ``lax.map`` over equal
    strips, each updated in cache by the ``b`` pivots of the block (``unroll`` fused per
    pass), as `_minplus_update` does for whole rows. Reads the upper triangle of ``W``
    only (the lower is taken as its mirror).
    """
    n = W.shape[0]
    nb = -(-n // (2 * block)) * 2
    m, half = nb * block, nb // 2
    rows, cols, groups, per = _fold_layout(nb, block, W.dtype.itemsize)
    iu = jnp.arange(n)
    W = jnp.where(iu[:, None] <= iu[None, :], W, W.T)
    D = jnp.full((m, m), jnp.inf, W.dtype).at[:n, :n].set(W)
    idx = jnp.arange(n, m)
    D = D.at[idx, idx].set(0).reshape(nb, block, nb, block)
    # F[p, g, r, s, c]: row r of pair p's strip, slot s of column group g, column c
    F = D[rows, :, cols, :].reshape(half, groups, per, block, block).transpose(0, 1, 3, 2, 4)
    split = jnp.asarray(nb - np.arange(half), jnp.int32)  # slots of tile row p in pair p
    slot = jnp.arange(groups * per).reshape(groups, per)
    tiles_j = jnp.arange(nb)
    cols = jnp.asarray(cols)

    def phase(kb, F):
        lo, hi = jnp.minimum(tiles_j, kb), jnp.maximum(tiles_j, kb)
        p, t = _fold_slot(lo, hi, nb)
        tiles = F[p, t // per, :, t % per, :]  # (nb, b, b): tile (lo, hi)
        Rt = jnp.where((tiles_j < kb)[:, None, None], tiles.transpose(0, 2, 1), tiles)
        dkk = _floyd_scan(jax.lax.dynamic_index_in_dim(Rt, kb, 0, keepdims=False))
        R = Rt.transpose(1, 0, 2).reshape(block, m)  # pivot rows D[k, :]
        Rt = jnp.minimum(R, _minplus(dkk, R)).reshape(block, nb, block).transpose(1, 0, 2)
        Ct = Rt.transpose(0, 2, 1)  # D[I, k] = D[k, I]ᵀ, per tile row I: (nb, rows, k)

        def strip(args):
            f, pp, s = args  # f: (groups, b, per, b)
            Rf = Rt[cols[pp]].reshape(groups, per, block, block).transpose(0, 2, 1, 3)
            Cp, Cq = Ct[pp].T, Ct[nb - 1 - pp].T  # (k, rows)
            Cf = jnp.where(slot[:, None, None, :] < s, Cp[None, :, :, None], Cq[None, :, :, None])

            def group(a):  # (b, per, b) tile row block, (k, b, per), (k, per, b)
                d, c, r = a

                def body(k, d):
                    return jnp.minimum(d, c[k][:, :, None] + r[k][None, :, :])

                return jax.lax.fori_loop(0, block, body, d, unroll=unroll)

            return jax.lax.map(group, (f, Cf, Rf))

        return jax.lax.map(strip, (F, jnp.arange(half), split))

    F = jax.lax.fori_loop(0, nb, phase, F)
    a = jnp.arange(nb)
    lo, hi = jnp.minimum(a[:, None], a[None, :]), jnp.maximum(a[:, None], a[None, :])
    p, t = _fold_slot(lo, hi, nb)
    tiles = F[p, t // per, :, t % per, :]  # (nb, nb, b, b): tile (lo, hi)
    tiles = jnp.where((a[:, None] > a[None, :])[:, :, None, None], tiles.swapaxes(2, 3), tiles)
    return tiles.transpose(0, 2, 1, 3).reshape(m, m)[:n, :n]


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
    """Raise `DisconnectedGraphError` naming the components and the fix."""
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
