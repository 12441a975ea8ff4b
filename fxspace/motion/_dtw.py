"""Dynamic time warping in JAX: an anti-diagonal wavefront ``lax.scan`` and a backtrack.

Cost (DESIGN.md): ``sqrt(Σ ||a_i − b_j||²)`` along the optimal path with steps (1,0),
(0,1), (1,1) and no window — the same number as ``dtaidistance.dtw_ndim.distance``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import _is_tracer, as_float_array, check_bool, check_int
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, check_result, is_successful, result_from_flags

__all__ = ["DTWResult", "dtw", "dtw_batch", "dtw_padded", "dtw_cost_matrix", "warp_from_path"]


@dataclasses.dataclass(frozen=True)
class DTWResult:
    """The result of a DTW (a JAX pytree; unpacks as ``cost, path = dtw(a, b)``).

    - ``cost``: ``sqrt`` of the accumulated squared distance on the optimal path.
    - ``path``: ``(L, 2)`` int pairs ``(i, j)`` from ``(0, 0)`` to ``(n-1, m-1)``; from
      `dtw_padded` / `dtw_batch` (and `dtw` under ``jit``/``vmap``) it is ``(n+m-1, 2)``
      with rows ``-1`` after the last step. ``path_length`` (a property) counts the valid
      rows.
    - ``result``: a `RESULTS` member — ``nonfinite_input`` when a frame holds NaN/inf
      (then ``cost`` is NaN and ``path`` holds only ``-1`` rows: no plausible path),
      ``successful`` otherwise.
    - ``num_steps``: anti-diagonals swept (``n + m − 1``); ``stats``: ``{"max_steps": n + m
      − 1, "path_length": L}``.
    """

    cost: Float[Array, ""]
    path: Int[Array, "L 2"]
    result: Any = dataclasses.field(default_factory=lambda: RESULTS.successful)
    num_steps: Any = 0
    stats: dict = dataclasses.field(default_factory=dict)

    @property
    def path_length(self) -> Int[Array, ""]:
        return jnp.sum(self.path[..., 0] >= 0, axis=-1)

    @property
    def converged(self):
        return is_successful(self.result)

    def __iter__(self):
        return iter((self.cost, self.path))

    def __getitem__(self, i):
        return (self.cost, self.path)[i]

    def __len__(self) -> int:
        return 2


jax.tree_util.register_dataclass(
    DTWResult, data_fields=["cost", "path", "result", "num_steps", "stats"], meta_fields=[]
)


def dtw_cost_matrix(a: Float[Array, "n d"], b: Float[Array, "m d"]) -> Float[Array, "n m"]:
    """Squared Euclidean distances ``||a_i − b_j||²`` (GEMM form, clipped at 0).

    Both sequences are divided by their largest magnitude before squaring (and the result
    multiplied back), so float32 frames at 1e-25 or 1e18 neither underflow nor overflow
    in the intermediate products; NaN frames give NaN rows/columns."""
    c, sc = _scaled_cost_matrix(*_check_frames(a, b, ndim=2))
    return c * sc**2


def _scaled_cost_matrix(a, b):
    """``(C / sc², sc)``: the squared distances of `dtw_cost_matrix` divided by the
    squared common scale (finite for any finite input), and that scale."""
    sc = jnp.maximum(jnp.max(jnp.abs(jnp.where(jnp.isfinite(a), a, 0.0))),
                     jnp.max(jnp.abs(jnp.where(jnp.isfinite(b), b, 0.0))))  # fmt: skip
    sc = jax.lax.stop_gradient(jnp.where(sc > 0, sc, 1.0))
    a, b = a / sc, b / sc
    aa = jnp.sum(a * a, axis=-1)
    bb = jnp.sum(b * b, axis=-1)
    ab = jnp.matmul(a, b.T, precision=jax.lax.Precision.HIGHEST)
    return jnp.maximum(aa[:, None] + bb[None, :] - 2.0 * ab, 0.0), sc


def _check_frames(a, b, ndim: int):
    """``a``, ``b`` as float arrays of rank ``ndim`` (frames, features last) sharing the
    feature size, non-empty; NaN/inf kept (reported by the result)."""
    a = as_float_array(a, "a", finite="allow")
    b = as_float_array(b, "b", finite="allow")
    if a.ndim != ndim or b.ndim != ndim or a.shape[-1] != b.shape[-1]:
        what = "(n, d) and (m, d)" if ndim == 2 else "(B, n, d) and (B, m, d)"
        raise FxspaceError(f"a and b must be {what} with the same d, got {a.shape} and {b.shape}")
    return a, b


def _check_valid(v, name: str, size: int):
    """A concrete ``n_valid``/``m_valid`` must lie in ``[1, size]``; traced ones pass."""
    if v is None or _is_tracer(v):
        return v
    arr = np.asarray(v) if not isinstance(v, str | bytes) else None
    if arr is None or arr.dtype.kind not in "iu" or arr.size == 0:
        raise FxspaceError(f"{name} must hold integer frame counts, got {v!r}")
    if np.any(arr < 1) or np.any(arr > size):
        raise FxspaceError(f"{name} must lie in [1, {size}] (valid frames), got {arr.tolist()}")
    return v


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
    """DTW with a fixed-shape result (jit/vmap friendly); see `DTWResult`.

    ``n_valid``/``m_valid`` (traced ints, default the full lengths) use only the first rows
    of padded inputs, so sequences of different lengths share one compilation and can be
    ``vmap``ped together. O(n·m·d) for the cost matrix (one GEMM) + O(n·m) for the
    wavefront over the ``n + m − 1`` anti-diagonals (``lax.scan``) + O(n + m) backtrack.
    """
    a, b = _check_frames(a, b, ndim=2)
    with_path = check_bool(with_path, "with_path")
    n, m = a.shape[0], b.shape[0]
    for v, nm in ((n_valid, "n_valid"), (m_valid, "m_valid")):
        if v is not None and np.ndim(v) != 0:
            raise FxspaceError(f"{nm} must be a scalar frame count, got shape {np.shape(v)}")
    n_valid = _check_valid(n_valid, "n_valid", n)
    m_valid = _check_valid(m_valid, "m_valid", m)
    nv = n if n_valid is None else n_valid
    mv = m if m_valid is None else m_valid
    rows_a = jnp.all(jnp.isfinite(a), axis=-1) | (jnp.arange(n) >= nv)
    rows_b = jnp.all(jnp.isfinite(b), axis=-1) | (jnp.arange(m) >= mv)
    bad = ~(jnp.all(rows_a) & jnp.all(rows_b))
    c, sc = _scaled_cost_matrix(a, b)  # scaled: frames at 1e30 neither overflow nor
    acc = _accumulate(c, nv, mv)  # give an inf cost with a meaningless path
    cost = jnp.where(bad, jnp.nan, jnp.sqrt(acc[nv + mv - 2, nv - 1]) * sc)
    overflow = ~bad & ~jnp.isfinite(cost)  # the cost itself beyond the dtype's range
    result = result_from_flags(converged=True, nonfinite_input=bad, nonfinite_output=overflow)
    steps = jnp.asarray(n + m - 1, jnp.int32)
    if not with_path:
        stats = {"max_steps": steps, "path_length": jnp.zeros((), jnp.int32)}
        return DTWResult(cost, jnp.zeros((0, 2), jnp.int32), result, steps, stats)
    path, length = _backtrack(acc, n, m, nv, mv)
    path = jnp.where(bad, -1, path)  # no plausible path from NaN frames
    length = jnp.where(bad, 0, length)
    return DTWResult(cost, path, result, steps, {"max_steps": steps, "path_length": length})


_dtw_jit = jax.jit(dtw_padded, static_argnames="with_path")


def dtw(
    a: Float[Array, "n d"], b: Float[Array, "m d"], with_path: bool = True, *, throw: bool = False
) -> DTWResult:
    """Dynamic time warping of two sequences (rows are frames; 1-D inputs are scalar series).

    **Arguments:** ``a`` ``(n, d)``, ``b`` ``(m, d)`` float arrays; ``with_path=False`` skips
    the backtrack.

    **Returns:** ``DTWResult(cost, path)``: ``cost = sqrt(Σ ||a_i − b_j||²)``
    on the optimal warping path (steps (1,0), (0,1), (1,1), no window; equals
    ``dtaidistance.dtw_ndim.distance``), ``path`` ``(L, 2)``. Called eagerly the path is
    trimmed to its length; under ``jit``/``vmap`` it is padded with ``-1`` rows (see
    `dtw_padded`). A NaN/inf frame gives ``cost = nan``, an empty path and ``.result ==
    RESULTS.nonfinite_input`` (``throw=True`` raises `FxspaceError` instead).
    """
    if any(getattr(x, "shape", (1,))[:1] == (0,) for x in (a, b)):
        raise FxspaceError("a and b must have at least one frame each")
    a = as_float_array(a, "a", finite="allow")
    b = as_float_array(b, "b", finite="allow")
    with_path = check_bool(with_path, "with_path")
    throw = check_bool(throw, "throw")
    if a.ndim == 1:
        a = a[:, None]
    if b.ndim == 1:
        b = b[:, None]
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise FxspaceError(
            f"a and b must be (n, d) and (m, d) with the same d, got {a.shape} and {b.shape}"
        )
    if a.shape[0] == 0 or b.shape[0] == 0:
        raise FxspaceError("a and b must have at least one frame each")
    if not jnp.issubdtype(a.dtype, jnp.floating):
        a = a.astype(jnp.result_type(float))
    b = b.astype(a.dtype)
    traced = isinstance(a, jax.core.Tracer) or isinstance(b, jax.core.Tracer)
    res = dtw_padded(a, b, with_path) if traced else _dtw_jit(a, b, with_path=with_path)
    if not (traced or not with_path):
        res = dataclasses.replace(res, path=res.path[: int(res.path_length)])
    return check_result(res.result, throw, "dtw", res)


def warp_from_path(path: Int[Array, "L 2"], n_ref: int) -> Float[Array, " n_ref"]:
    """Time-warp function ``C(u)``: for each reference frame ``u`` (path column 0), the mean
    matched frame of the other sequence (column 1), made non-decreasing. Padding rows
    (``-1``) are ignored."""
    n_ref = check_int(n_ref, "n_ref", low=1)
    if not _is_tracer(path):
        try:
            p = np.asarray(path)
        except (TypeError, ValueError) as e:
            raise FxspaceError(f"path must be an (L, 2) integer array ({e})") from None
        if p.ndim != 2 or p.shape[1] != 2 or p.dtype.kind not in "iu":
            raise FxspaceError(
                f"path must be (L, 2) integer frame pairs, got {p.dtype} of shape {p.shape}"
            )
        if p.size and (p.min() < -1 or p[:, 0].max() >= n_ref):
            raise FxspaceError(f"path must hold frames in [0, {n_ref - 1}] (or -1 padding)")
    path = jnp.asarray(path)
    if path.ndim != 2 or path.shape[1] != 2:
        raise FxspaceError(f"path must be (L, 2) frame pairs, got shape {path.shape}")
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
    """DTW of ``B`` pairs at once (jittable): fields of `DTWResult` gain a leading
    ``B`` axis; paths are padded (see `dtw_padded`). ``b`` (or ``a``) may be a single
    ``(m, d)`` sequence shared by all pairs.

    ``method``: ``"vmap"`` batches the wavefront (best on GPU), ``"map"`` runs the pairs one
    after another inside one compiled loop (``lax.map``; best on CPU, where a vmapped scan
    is memory-bound), ``"auto"`` picks ``"map"`` on CPU and ``"vmap"`` elsewhere.
    """
    if method not in ("auto", "map", "vmap"):
        raise FxspaceError(f"method must be 'auto', 'map' or 'vmap', got {method!r}")
    with_path = check_bool(with_path, "with_path")
    a = as_float_array(a, "a", finite="allow")
    b = as_float_array(b, "b", finite="allow")
    if a.ndim not in (2, 3) or b.ndim not in (2, 3) or a.ndim + b.ndim == 4:
        raise FxspaceError(f"a and b must be (B, n, d) and (B, m, d), got {a.shape} and {b.shape}")
    if b.ndim == 2:
        b = jnp.broadcast_to(b, (a.shape[0],) + b.shape)
    if a.ndim == 2:
        a = jnp.broadcast_to(a, (b.shape[0],) + a.shape)
    if a.ndim != 3 or b.ndim != 3 or a.shape[0] != b.shape[0] or a.shape[2] != b.shape[2]:
        raise FxspaceError(f"a and b must be (B, n, d) and (B, m, d), got {a.shape} and {b.shape}")
    B = a.shape[0]
    for v, nm, size in ((n_valid, "n_valid", a.shape[1]), (m_valid, "m_valid", b.shape[1])):
        if v is not None and np.shape(v) != (B,):
            raise FxspaceError(f"{nm} must have shape ({B},), got {np.shape(v)}")
        _check_valid(v, nm, size)
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
