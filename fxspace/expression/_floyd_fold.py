"""Folded blocked Floyd–Warshall for an undirected graph (`_floyd_folded`): only the upper
tiles are stored and updated, tile rows ``p`` and ``nb-1-p`` sharing one strip, half the
O(n³) work of `_floyd_blocked`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from fxspace.expression._floyd_kernels import _floyd_scan, _minplus

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
