"""Dynamic time warping in JAX: an anti-diagonal wavefront ``lax.scan`` and a backtrack.

Cost (DESIGN.md): ``sqrt(Σ ||a_i − b_j||²)`` along the optimal path with steps (1,0),
(0,1), (1,1) and no window — the same number as ``dtaidistance.dtw_ndim.distance``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

__all__ = ["DTWResult", "dtw", "dtw_batch", "dtw_padded", "dtw_cost_matrix", "warp_from_path"]


class DTWResult(NamedTuple):
    """``cost``: ``sqrt`` of the accumulated squared distance on the optimal path.
    ``path``: ``(L, 2)`` int pairs ``(i, j)`` from ``(0, 0)`` to ``(n-1, m-1)``; from
    :func:`dtw_padded` / :func:`dtw_batch` (and :func:`dtw` under ``jit``/``vmap``) it is
    ``(n+m-1, 2)`` with rows ``-1`` after the last step. ``path_length`` (a property) counts
    the valid rows. Unpacks as ``cost, path = dtw(a, b)``."""

    cost: Float[Array, ""]
    path: Int[Array, "L 2"]

    @property
    def path_length(self) -> Int[Array, ""]:
        return jnp.sum(self.path[..., 0] >= 0, axis=-1)


def dtw_cost_matrix(a: Float[Array, "n d"], b: Float[Array, "m d"]) -> Float[Array, "n m"]:
    """Squared Euclidean distances ``||a_i − b_j||²`` (GEMM form, clipped at 0)."""
    aa = jnp.sum(a * a, axis=-1)
    bb = jnp.sum(b * b, axis=-1)
    ab = jnp.matmul(a, b.T, precision=jax.lax.Precision.HIGHEST)
    return jnp.maximum(aa[:, None] + bb[None, :] - 2.0 * ab, 0.0)


def _accumulate(c: Float[Array, "n m"], n_valid=None, m_valid=None) -> Float[Array, "k n"]:
    """Accumulated cost on anti-diagonals: ``acc[k, i] = D(i, k - i)`` (inf outside; rows
    ``>= n_valid`` and columns ``>= m_valid`` count as outside)."""
    n, m = c.shape
    n_valid = n if n_valid is None else n_valid
    m_valid = m if m_valid is None else m_valid
    inf = jnp.asarray(jnp.inf, c.dtype)
    K = n + m - 1
    # skew once: s[k, i] = c[i, k - i] (inf outside the matrix), so each scan step reads a row
    cols = jnp.arange(K)[:, None] - jnp.arange(n)[None, :]
    valid = (cols >= 0) & (cols < m_valid) & (jnp.arange(n)[None, :] < n_valid)
    s = jnp.where(valid, c[jnp.arange(n)[None, :], jnp.clip(cols, 0, m - 1)], inf)
    s = s.at[0, 0].set(c[0, 0])
    pad = jnp.full((1,), inf, c.dtype)

    def step(carry, sk):
        prev, prev2 = carry  # diagonals k-1 and k-2
        left = jnp.concatenate([pad, prev[:-1]])  # D(i-1, j)
        diag = jnp.concatenate([pad, prev2[:-1]])  # D(i-1, j-1)
        cur = sk + jnp.minimum(jnp.minimum(left, prev), diag)
        return (cur, prev), cur

    first = jnp.where(jnp.arange(n) == 0, s[0], inf)
    init = (first, jnp.full((n,), inf, c.dtype))
    _, acc = jax.lax.scan(step, init, s[1:])
    return jnp.concatenate([first[None], acc], axis=0)


def _backtrack(
    acc: Float[Array, "k n"], n: int, m: int, n_valid=None, m_valid=None
) -> tuple[Int[Array, "L 2"], Int[Array, ""]]:
    """Optimal path from (n_valid-1, m_valid-1) back to (0, 0); ties prefer the diagonal
    step, then (i-1, j)."""
    L = n + m - 1
    n_valid = n if n_valid is None else n_valid
    m_valid = m if m_valid is None else m_valid
    inf = jnp.asarray(jnp.inf, acc.dtype)

    def get(i, j):
        ok = (i >= 0) & (j >= 0)
        return jnp.where(ok, acc[jnp.clip(i + j, 0, L - 1), jnp.clip(i, 0, n - 1)], inf)

    def step(carry, _):
        i, j, done = carry
        cand = jnp.stack([get(i - 1, j - 1), get(i - 1, j), get(i, j - 1)])
        pick = jnp.argmin(cand)
        di = jnp.where(pick == 2, 0, 1)
        dj = jnp.where(pick == 1, 0, 1)
        out = jnp.where(done, -1, jnp.stack([i, j]))
        at0 = (i == 0) & (j == 0)
        ni = jnp.where(at0 | done, i, i - di)
        nj = jnp.where(at0 | done, j, j - dj)
        return (ni, nj, done | at0), out

    (_, _, _), rev = jax.lax.scan(
        step,
        (jnp.asarray(n_valid - 1), jnp.asarray(m_valid - 1), jnp.asarray(False)),
        None,
        length=L,
    )
    length = jnp.sum(rev[:, 0] >= 0)
    # rev holds the path end → start followed by -1 rows; reverse the valid prefix
    idx = jnp.arange(L)
    src = jnp.where(idx < length, length - 1 - idx, idx)
    path = rev[src]
    return path, length


def dtw_padded(
    a: Float[Array, "n d"],
    b: Float[Array, "m d"],
    with_path: bool = True,
    n_valid: Int[Array, ""] | int | None = None,
    m_valid: Int[Array, ""] | int | None = None,
) -> DTWResult:
    """DTW with a fixed-shape result (jit/vmap friendly); see :class:`DTWResult`.

    ``n_valid``/``m_valid`` (traced ints, default the full lengths) use only the first rows
    of padded inputs, so sequences of different lengths share one compilation and can be
    ``vmap``ped together. O(n·m·d) for the cost matrix (one GEMM) + O(n·m) for the
    wavefront over the ``n + m − 1`` anti-diagonals (``lax.scan``) + O(n + m) backtrack.
    """
    n, m = a.shape[0], b.shape[0]
    nv = n if n_valid is None else n_valid
    mv = m if m_valid is None else m_valid
    acc = _accumulate(dtw_cost_matrix(a, b), nv, mv)
    cost = jnp.sqrt(acc[nv + mv - 2, nv - 1])
    if not with_path:
        return DTWResult(cost, jnp.zeros((0, 2), jnp.int32))
    path, length = _backtrack(acc, n, m, nv, mv)
    return DTWResult(cost, path)


_dtw_jit = jax.jit(dtw_padded, static_argnames="with_path")


def dtw(a: Float[Array, "n d"], b: Float[Array, "m d"], with_path: bool = True) -> DTWResult:
    """Dynamic time warping of two sequences (rows are frames; 1-D inputs are scalar series).

    **Arguments:** ``a`` ``(n, d)``, ``b`` ``(m, d)`` float arrays; ``with_path=False`` skips
    the backtrack.

    **Returns:** ``DTWResult(cost, path)``: ``cost = sqrt(Σ ||a_i − b_j||²)``
    on the optimal warping path (steps (1,0), (0,1), (1,1), no window; equals
    ``dtaidistance.dtw_ndim.distance``), ``path`` ``(L, 2)``. Called eagerly the path is
    trimmed to its length; under ``jit``/``vmap`` it is padded with ``-1`` rows (see
    :func:`dtw_padded`).
    """
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    if a.ndim == 1:
        a = a[:, None]
    if b.ndim == 1:
        b = b[:, None]
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(
            f"a and b must be (n, d) and (m, d) with the same d, got {a.shape} and {b.shape}"
        )
    if a.shape[0] == 0 or b.shape[0] == 0:
        raise ValueError("a and b must have at least one frame each")
    if not jnp.issubdtype(a.dtype, jnp.floating):
        a = a.astype(jnp.result_type(float))
    b = b.astype(a.dtype)
    traced = isinstance(a, jax.core.Tracer) or isinstance(b, jax.core.Tracer)
    res = dtw_padded(a, b, with_path) if traced else _dtw_jit(a, b, with_path=with_path)
    if traced or not with_path:
        return res
    return DTWResult(res.cost, res.path[: int(res.path_length)])


def warp_from_path(path: Int[Array, "L 2"], n_ref: int) -> Float[Array, " n_ref"]:
    """Time-warp function ``C(u)``: for each reference frame ``u`` (path column 0), the mean
    matched frame of the other sequence (column 1), made non-decreasing. Padding rows
    (``-1``) are ignored."""
    valid = path[:, 0] >= 0
    i = jnp.where(valid, path[:, 0], 0)
    s = jnp.zeros(n_ref).at[i].add(jnp.where(valid, path[:, 1], 0).astype(jnp.result_type(float)))
    c = jnp.zeros(n_ref).at[i].add(valid.astype(s.dtype))
    w = s / jnp.maximum(c, 1.0)
    return jax.lax.cummax(w)


def dtw_batch(
    a: Float[Array, "B n d"],
    b: Float[Array, "B m d"],
    with_path: bool = True,
    n_valid: Int[Array, " B"] | None = None,
    m_valid: Int[Array, " B"] | None = None,
    method: str = "auto",
) -> DTWResult:
    """DTW of ``B`` pairs at once (jittable): fields of :class:`DTWResult` gain a leading
    ``B`` axis; paths are padded (see :func:`dtw_padded`). ``b`` (or ``a``) may be a single
    ``(m, d)`` sequence shared by all pairs.

    ``method``: ``"vmap"`` batches the wavefront (best on GPU), ``"map"`` runs the pairs one
    after another inside one compiled loop (``lax.map``; best on CPU, where a vmapped scan
    is memory-bound), ``"auto"`` picks ``"map"`` on CPU and ``"vmap"`` elsewhere.
    """
    if method not in ("auto", "map", "vmap"):
        raise ValueError(f"method must be 'auto', 'map' or 'vmap', got {method!r}")
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    if b.ndim == 2:
        b = jnp.broadcast_to(b, (a.shape[0],) + b.shape)
    if a.ndim == 2:
        a = jnp.broadcast_to(a, (b.shape[0],) + a.shape)
    if a.ndim != 3 or b.ndim != 3 or a.shape[0] != b.shape[0] or a.shape[2] != b.shape[2]:
        raise ValueError(f"a and b must be (B, n, d) and (B, m, d), got {a.shape} and {b.shape}")
    B = a.shape[0]
    nv = jnp.full((B,), a.shape[1]) if n_valid is None else jnp.asarray(n_valid)
    mv = jnp.full((B,), b.shape[1]) if m_valid is None else jnp.asarray(m_valid)
    if method == "auto":
        method = "map" if jax.default_backend() == "cpu" else "vmap"

    def one(args):
        x, y, n, m = args
        return dtw_padded(x, y, with_path, n, m)

    if method == "vmap":
        return jax.vmap(one)((a, b, nv, mv))
    return jax.lax.map(one, (a, b, nv, mv))
