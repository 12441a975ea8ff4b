"""Truncated fuzzy c-means a block of points at a time, in this process or on Dask.

The steps of `._fcm_sparse` (Bezdek's updates over each point's ``p`` nearest centres,
the nearest kept cheap by a candidate list checked against the centres' drift), with the
points cut into blocks of at most ``rows_per_task`` (as few as that allows, of equal
sizes ±1). Each step, every block

1. finds its points' nearest ``p`` centres (its candidate list, or a full pass over
   every centre when the list may be stale: decided per block),
2. computes their truncated memberships ``u`` and
3. returns its partial sums ``[Σ_i u_ikᵐ, Σ_i u_ikᵐ x_i]`` ``(c, 1 + d)`` and its share
   of the objective ``Σ_i Σ_k u_ikᵐ d_ik²`` at the centres it was given;

this process adds the partials in block order (``((s₀ + s₁) + s₂) + …``, elementwise),
sets ``v_k = Σ uᵐx / Σ uᵐ`` (a centre with no mass stays), and sends the new centres and
their largest move to the next step. A block's points and candidate list stay where the
block runs (on Dask: sent once to one worker, which keeps them between steps and runs
all of that block's tasks), so a step sends only the centres out (``c × d``) and each
block's partials back (``c × (1 + d)``: 160 centres in 2-D, 3.8 kB in float64).
With ``accelerate`` (the default of `fxspace.cluster.fuzzy_cmeans` with blocks) this
process runs SQUAREM cycles on these steps (`_squarem`): extrapolated centres, kept only
where the objective from their own pass does not rise; the stop is still one plain step
moving no centre more than ``tol`` × the spread, and ``drift`` is the largest move
between the centres of consecutive passes.

Every block runs the same jit-compiled kernel, on the same block, here or on a worker,
and the reduction and the update are this process's numpy, so ``client=None`` and a
Dask client give the same centres, memberships and step count, bit for bit. The
numbers depend on ``rows_per_task`` (the blocks, the order of the sums) and differ from
`._fcm_sparse`'s single jit loop in the last bits (its sums run over all points at once,
its full passes are for all points at once); the clustering is the same fixed point.
"""

from __future__ import annotations

import uuid
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._validate import _is_tracer, check_int, check_scalar
from fxspace.cluster._fcm import _tiny
from fxspace.cluster._fcm_sparse import (
    _CAND,
    SparseFCMResult,
    _assign,
    _full_pass,
    _prepare,
    _rank_mask,
)
from fxspace.errors import FxspaceError
from fxspace.results import check_result, result_from_flags

__all__: list[str] = []

_ROWS = 65536  # points a block by default


def _sums(x, idx, um, c):
    """``[Σ_i u_ikᵐ, Σ_i u_ikᵐ x_i]`` ``(c, 1 + d)`` over the kept entries (one scatter)."""
    vals = jnp.concatenate([um[..., None], um[..., None] * x[:, None, :]], axis=-1)
    return jax.ops.segment_sum(vals.reshape(-1, 1 + x.shape[1]), idx.reshape(-1), num_segments=c)


@partial(jax.jit, static_argnames=("m", "p", "chunk"))
def _block_step(x, v, cand, reach, drift, m, p, chunk):
    """One step on one block: ``(cand, reach, drift, partial sums, objective share)``
    (module docstring; the share ``Σ_i Σ_k u_ikᵐ d_ik²`` at the centres ``v`` given).
    The candidate list is exact while each point's p-th distance ≤ ``reach − drift``."""
    c, k = v.shape[0], cand.shape[1]
    top = jnp.broadcast_to(jnp.arange(k) < p, cand.shape)

    def full():
        idx, d2 = _full_pass(x, v, k, chunk)
        r = jnp.sqrt(d2[:, -1]) if k < c else jnp.full(reach.shape, jnp.inf, x.dtype)
        return idx, d2, top, r, jnp.zeros((), x.dtype)

    d2 = jnp.sum(jnp.square(v[cand] - x[:, None, :]), axis=-1)
    keep = _rank_mask(d2, p)
    pth = jnp.sqrt(jnp.max(jnp.where(keep, d2, -jnp.inf), axis=1))
    exact = jnp.all(pth <= reach - drift)
    cand, d2, keep, reach, drift = jax.lax.cond(exact, lambda: (cand, d2, keep, reach, drift), full)
    d2 = jnp.maximum(d2, _tiny(x.dtype))
    w = jnp.where(keep, 1.0 / d2 if m == 2.0 else jnp.power(d2, -1.0 / (m - 1.0)), 0.0)
    u = w / jnp.sum(w, axis=1, keepdims=True)
    um = u * u if m == 2.0 else jnp.power(u, m)
    return cand, reach, drift, _sums(x, cand, um, c), jnp.sum(um * d2)


_block_assign = jax.jit(_assign, static_argnames=("m", "p", "chunk"))


_THREADS = 2  # blocks run at once here (each block's step is its own computation)
_STATES: dict[tuple[str, int], tuple] = {}  # (run, block) -> state, in each process


def _init(run: str, b: int, x: np.ndarray, c: int) -> None:
    """Keep block ``b``'s state ``(x, cand, reach, drift)`` in this process (worker);
    ``reach = −inf``: its first step runs a full pass."""
    with jax.enable_x64(x.dtype == np.float64):
        k = min(_CAND, c)
        n = x.shape[0]
        _STATES[run, b] = (jnp.asarray(x), jnp.zeros((n, k), jnp.int32),
                           jnp.full((n,), -jnp.inf, x.dtype), jnp.zeros((), x.dtype))  # fmt: skip


def _state(run: str, b: int) -> tuple:
    try:
        return _STATES[run, b]
    except KeyError:
        raise FxspaceError(
            f"block {b} of the FCM is gone from its worker (the worker restarted or left): "
            "run the clustering again"
        ) from None


def _step(run: str, b: int, v: np.ndarray, moved, m: float, p: int, chunk: int) -> tuple:
    """One step of block ``b``: its state advanced; its partial sums and its share of the
    objective at ``v`` returned."""
    x, cand, reach, drift = _state(run, b)
    with jax.enable_x64(v.dtype == np.float64):
        out = _block_step(x, jnp.asarray(v), cand, reach, drift + moved, m, p, chunk)
        _STATES[run, b] = (x, *out[:3])
        return np.asarray(out[3]), np.asarray(out[4])


def _final(run: str, b: int, v: np.ndarray, m: float, p: int, chunk: int):
    """``(indices, memberships, objective)`` of block ``b``'s points at the centres ``v``."""
    x = _state(run, b)[0]
    with jax.enable_x64(v.dtype == np.float64):
        idx, u, obj = _block_assign(x, jnp.asarray(v), m, p, min(chunk, x.shape[0]))
        return np.asarray(idx), np.asarray(u), np.asarray(obj)


def _drop(run: str) -> None:
    for key in [k for k in _STATES if k[0] == run]:
        del _STATES[key]


class _Blocks:
    """The blocks, each kept where it runs (this process, or one Dask worker that keeps
    its points and state between steps); a call on every block, results in block order."""

    def __init__(self, x: np.ndarray, rows: int, c: int, client):
        self.client, self.run = client, uuid.uuid4().hex
        # as few blocks as `rows` allows, of equal sizes (±1 point): the threads (or
        # workers) finish a step together, and every block runs one compiled kernel where
        # the sizes come out equal (10⁵ points: 2 × 50 000, not 65 536 + 34 464)
        parts = np.array_split(x, -(-len(x) // rows))
        self.blocks = range(len(parts))
        self.pool = None
        if client is None:
            for b, part in enumerate(parts):
                _init(self.run, b, part, c)
            if len(parts) > 1 and _THREADS > 1:  # one pool for every step (not one a step)
                self.pool = ThreadPoolExecutor(_THREADS, thread_name_prefix="fxspace-fcm")
            return
        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise FxspaceError("client has no workers: start some, or pass client=None")
        self.where = [[workers[b % len(workers)]] for b in self.blocks]
        sent = [
            client.scatter(part, workers=w, hash=False)
            for part, w in zip(parts, self.where, strict=True)
        ]
        self._call(_init, [(b, s, c) for b, s in zip(self.blocks, sent, strict=True)])

    def _call(self, fn, items) -> list:
        if self.client is None:
            if self.pool is None:
                return [fn(self.run, *it) for it in items]
            # XLA leaves cores idle in a block: the blocks of a step at once
            return list(self.pool.map(lambda it: fn(self.run, *it), items))
        futures = [self.client.submit(fn, self.run, *it, pure=False, workers=w,
                                      allow_other_workers=False)
                   for it, w in zip(items, self.where, strict=True)]  # fmt: skip
        return self.client.gather(futures)

    def step(self, *args) -> list[tuple]:
        return self._call(_step, [(b, *args) for b in self.blocks])

    def final(self, *args) -> list:
        return self._call(_final, [(b, *args) for b in self.blocks])

    def close(self) -> None:
        if self.client is None:
            if self.pool is not None:
                self.pool.shutdown(wait=True)
            _drop(self.run)
        else:
            self.client.run(_drop, self.run)


def _reduce(parts: list[np.ndarray], v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New centres from the blocks' partial sums, added in block order, and the masses
    ``Σ_i u_ikᵐ``."""
    tot = parts[0]
    for q in parts[1:]:
        tot = tot + q
    mass, num = tot[:, 0], tot[:, 1:]
    ok = mass > 0
    return np.where(ok[:, None], num / np.where(ok, mass, 1.0)[:, None], v), mass


def _move(a: np.ndarray, b: np.ndarray):
    """The largest centre move between ``a`` and ``b`` ``(c, d)`` (in their dtype)."""
    return a.dtype.type(np.max(np.sqrt(np.sum(np.square(a - b), axis=1))))


class _Map:
    """The FCM map ``G`` one block pass at a time: ``G(v)``, the objective ``J(v)`` (the
    blocks' shares added in block order, in float64) and the masses, from one pass; the
    blocks are told the largest move from the centres of the previous pass (``drift``)."""

    def __init__(self, blocks: _Blocks, m: float, p: int, chunk: int):
        self.blocks, self.args, self.last, self.passes = blocks, (m, p, chunk), None, 0

    def __call__(self, v: np.ndarray):
        moved = v.dtype.type(0) if self.last is None else _move(v, self.last)
        got = self.blocks.step(v, moved, *self.args)
        self.last, self.passes = v, self.passes + 1
        new, mass = _reduce([g[0] for g in got], v)
        obj = 0.0
        for g in got:
            obj += float(g[1])
        return new, obj, mass


def _plain(G: _Map, v: np.ndarray, tol_abs, max_steps: int):
    """Bezdek's steps ``v ← G(v)`` until no centre moves ``tol_abs``: ``(v, moved)``."""
    moved = v.dtype.type(np.inf)
    while G.passes < max_steps and moved >= tol_abs:
        new = G(v)[0]
        v, moved = new, _move(new, v)
    return v, moved


def _extrapolate(v0: np.ndarray, r: np.ndarray, q: np.ndarray, a: float) -> np.ndarray:
    """SQUAREM's point ``v₀ + 2αr + α²q`` (``α = 1``: ``v₂``), in ``v₀``'s dtype."""
    return (v0 + 2.0 * a * r + a * a * q).astype(v0.dtype)


def _squarem(G: _Map, v: np.ndarray, tol_abs, max_steps: int, stats: dict):
    """SQUAREM (Varadhan & Roland 2008, scheme S3 with the global safeguard of their R
    package) on the centres: ``(v, moved)``, ``v = G(w)`` with ``moved = |G(w) − w|``
    below ``tol_abs`` (or at the cap), ``w`` on the accepted path. A cycle from ``v₀``:
    ``v₁ = G(v₀)``, ``v₂ = G(v₁)``, ``r = v₁ − v₀``, ``q = v₂ − 2v₁ + v₀``,
    ``α = clip(|r|/|q|, 1, α_max)``, ``v' = v₀ + 2αr + α²q`` (``α = 1``: ``v' = v₂``),
    then one plain step ``G(v')`` as the next ``v₀``. ``v'`` is kept only if
    ``J(v') ≤ J(v₁) − Σ_k M_k |v₂ₖ − v₁ₖ|²`` (``M_k = Σ_i u_ikᵐ`` at ``v₁``): the objective
    of ``v₂`` with the memberships of ``v₁``, which bounds ``J(v₂)`` from above; else the
    cycle falls back to ``v₂``. ``α_max`` starts at 1 and is ×4 when reached and accepted
    (the package's rule); a refused ``α`` sets ``α_max = max(1, α/4)`` (the package
    divides ``α_max`` by 4 only when ``α`` reached it: on the truncated map, whose
    memberships jump when a point's ``p`` nearest change, long steps below ``α_max`` fail
    in runs, and this halves the passes they waste on 10⁵ frames). ``J`` at the points
    the cycles go on from never increases."""
    big, moved = 1.0, v.dtype.type(np.inf)
    while G.passes < max_steps:
        v0, (v1, _, _) = v, G(v)
        v, moved = v1, _move(v1, v0)
        if not moved >= tol_abs or G.passes >= max_steps:  # NaN stops too, as `_plain`
            break
        v2, j1, mass = G(v1)
        v, moved = v2, _move(v2, v1)
        if not moved >= tol_abs or G.passes >= max_steps:
            break
        r, q = v1 - v0, v2 - 2.0 * v1 + v0
        nq = float(np.sqrt(np.sum(np.square(q, dtype=np.float64))))
        a = min(big, float(np.sqrt(np.sum(np.square(r, dtype=np.float64)))) / nq) if nq else big
        a = max(a, 1.0)
        if a == 1.0:  # v' = v₂: its plain step starts the next cycle
            big = big * 4.0 if a == big else big
            continue
        vx = _extrapolate(v0, r, q, a)
        gx, jx, _ = G(vx)
        bound = j1 - float(np.sum(mass * np.sum(np.square(v2 - v1, dtype=np.float64), axis=1)))
        if np.isfinite(jx) and np.all(np.isfinite(gx)) and jx <= bound:
            stats["accepted"] += 1
            big = big * 4.0 if a == big else big
            v, moved = gx, _move(gx, vx)
            if moved < tol_abs:
                break
        else:
            stats["refused"] += 1
            big = max(1.0, a / 4.0)
    return v, moved


def blocked_fcm(x, v0, m: float, p: int, tol: float, max_steps: int, chunk: int,
                rows: int, client=None, accelerate: bool = True) -> SparseFCMResult:  # fmt: skip
    """Truncated FCM in blocks of ``rows`` points (module docstring): the same result
    with ``client=None`` and on a Dask client; ``accelerate``: SQUAREM cycles
    (`_squarem`), else plain steps. ``num_steps`` counts block passes either way."""
    x, v = np.asarray(x), np.asarray(v0, np.asarray(x).dtype)
    dt = x.dtype.type
    scale = dt(np.sqrt(np.mean(np.sum(np.square(x - np.mean(x, axis=0, keepdims=True)), axis=1))))
    tol_abs = dt(tol) * scale
    blocks = _Blocks(x, rows, v.shape[0], client)
    extra = {"accepted": 0, "refused": 0}
    try:
        G = _Map(blocks, m, p, chunk)
        if accelerate:
            v, moved = _squarem(G, v, tol_abs, max_steps, extra)
        else:
            v, moved = _plain(G, v, tol_abs, max_steps)
        steps = G.passes
        got = blocks.final(v, m, p, chunk)
    finally:
        blocks.close()
    idx = np.concatenate([g[0] for g in got])
    u = np.concatenate([g[1] for g in got])
    obj = got[0][2]
    for g in got[1:]:
        obj = obj + g[2]
    ok = bool(np.isfinite(obj) and np.all(np.isfinite(v)))
    bad_in = not (np.all(np.isfinite(x)) and np.all(np.isfinite(v0)))
    result = result_from_flags(converged=bool(moved < tol_abs) and ok,
                               nonfinite_input=bad_in, nonfinite_output=not ok)  # fmt: skip
    stats = {"max_steps": jnp.asarray(max_steps, jnp.int32), "moved": jnp.asarray(moved),
             "tol_abs": jnp.asarray(tol_abs)}  # fmt: skip
    if accelerate:
        stats.update({f"num_{k}": jnp.asarray(n, jnp.int32) for k, n in extra.items()})
    if bad_in:
        v, u, obj = (np.full_like(a, np.nan) for a in (v, u, obj))
    return SparseFCMResult(jnp.asarray(v), jnp.asarray(idx), jnp.asarray(u), jnp.asarray(obj),
                           jnp.asarray(steps, jnp.int32), result, stats)  # fmt: skip


def precompile(n: int, d: int, dtype, sizes, m: float, nearest: int, chunk: int,
               rows: int) -> None:
    """Compile, without running them, the block kernels that `fuzzy_cmeans` with
    ``nearest`` and ``rows_per_task`` (no client) will call, for each centre count in
    ``sizes``: the runs then find them compiled. A hierarchy's levels each need their own
    (one per centre count: ~0.5 s each on a CPU); `fxspace.navigation.build_hierarchy`
    compiles its later levels' in a thread beside the first level's run.

    **Arguments:** `n`, `d`: the points and their dimensions; `dtype`: theirs (float32 or
    float64); `sizes`: the centre counts; `m`, `nearest`, `chunk`, `rows`: as given to
    `fuzzy_cmeans` (``rows`` its ``rows_per_task``).

    **Example:** ``fx.cluster.precompile_fcm_blocks(100_000, 2, np.float32, [20, 40],
    2.0, 8, 8192, 65536)``"""
    n = check_int(n, "n", low=1)
    d = check_int(d, "d", low=1)
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise FxspaceError(f"dtype must be float32 or float64 (the points'), got {dtype!r}")
    if isinstance(sizes, (str, bytes)) or not hasattr(sizes, "__iter__"):
        raise FxspaceError(f"sizes must be a sequence of centre counts, got {sizes!r}")
    sizes = [check_int(c, "sizes[i]", low=1, high=n) for c in sizes]
    m = check_scalar(m, "m", low=1.0, low_open=True)
    nearest = check_int(nearest, "nearest", low=1)
    chunk = check_int(chunk, "chunk", low=1)
    rows = check_rows(rows, n)
    lens = sorted({len(a) for a in np.array_split(np.empty(n, bool), -(-n // rows))})
    ch = min(int(chunk), rows)
    sds = jax.ShapeDtypeStruct
    with jax.enable_x64(bool(dt == np.float64)):
        for c in sizes:
            p, k = min(int(nearest), int(c)), min(_CAND, int(c))
            for nb in lens:
                x, v = sds((nb, d), dt), sds((int(c), d), dt)
                _block_step.lower(x, v, sds((nb, k), np.int32), sds((nb,), dt), sds((), dt),
                                  float(m), p, ch).compile()  # fmt: skip
                _block_assign.lower(x, v, float(m), p, min(ch, nb)).compile()


def check_rows(rows_per_task, n: int) -> int:
    """``rows_per_task`` as an int in ``[1, n]``, or an `FxspaceError` naming the fix."""
    if isinstance(rows_per_task, bool) or not isinstance(rows_per_task, (int, np.integer)):
        raise FxspaceError(f"rows_per_task must be an int >= 1 (points a block), got "
                           f"{rows_per_task!r}")  # fmt: skip
    if rows_per_task < 1:
        raise FxspaceError(f"rows_per_task must be >= 1 (points a block), got {rows_per_task}")
    return min(int(rows_per_task), n)


def blocked_fuzzy_cmeans(x, n_clusters, m=2.0, *, nearest=8, key=None, init_centers=None,
                         tol=1e-4, max_steps=300, chunk=8192, rows_per_task=None,
                         client=None, throw=False, accelerate=True) -> SparseFCMResult:  # fmt: skip
    """`fxspace.cluster.fuzzy_cmeans` with ``nearest`` in blocks of ``rows_per_task``
    points (default 65 536), here or as Dask tasks on ``client`` (module docstring);
    ``accelerate``: SQUAREM cycles (`_squarem`) instead of plain steps."""
    if not isinstance(accelerate, (bool, np.bool_)):
        raise FxspaceError(f"accelerate must be True or False, got {accelerate!r}")
    if _is_tracer(x) or _is_tracer(init_centers):
        raise FxspaceError(
            "rows_per_task and client run the FCM's steps from Python, not under jit/vmap: "
            "call fuzzy_cmeans outside jit, or leave rows_per_task and client unset"
        )
    x, c, p, v0 = _prepare(x, n_clusters, m, nearest, key, init_centers, throw)
    rows = check_rows(_ROWS if rows_per_task is None else rows_per_task, x.shape[0])
    res = blocked_fcm(x, v0, float(m), p, float(tol), int(max_steps),
                      min(int(chunk), rows), rows, client, bool(accelerate))  # fmt: skip
    return check_result(res.result, throw, "fuzzy_cmeans", res)
