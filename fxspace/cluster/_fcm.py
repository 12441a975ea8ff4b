"""Fuzzy c-means (Bezdek) as a jitted fixed point, with k-means++ seeding and restarts.

The objective (Bezdek 1981; seed paper §4, eq. for the hierarchy levels) is

    J_m(U, V) = Σ_i Σ_k u_ik^m ‖x_i − v_k‖²,   Σ_k u_ik = 1,

minimised by alternating the two first-order conditions

    v_k  = Σ_i u_ik^m x_i / Σ_i u_ik^m                                  (centres)
    u_ik = d_ik^{-2/(m-1)} / Σ_j d_ij^{-2/(m-1)},  d_ik = ‖x_i − v_k‖     (memberships)

At the memberships that are optimal for V the objective has the closed form
``J = Σ_i s_i^{1-m}`` with ``s_i = Σ_k d_ik^{-2/(m-1)}``, which is what we report.

Cost per iteration: O(n c d) time and O(n c) memory; the (n, c, d) difference tensor
is never formed (small d is unrolled over the feature axis, large d uses the
``‖x‖² − 2 x·v + ‖v‖²`` expansion).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import (
    _is_tracer,
    as_float_array,
    check_finite,
    check_key,
    check_scalar,
    checked,
)
from fxspace.cluster._kmeanspp import kmeanspp_extend as kmeanspp_extend
from fxspace.cluster._kmeanspp import kmeanspp_init as kmeanspp_init
from fxspace.cluster._kmeanspp import squared_distances as squared_distances
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, check_result, result_from_flags

__all__ = [
    "FCMResult",
    "fuzzy_cmeans",
    "squared_distances",
    "fcm_memberships",
    "kmeanspp_init",
    "kmeanspp_extend",
    "fcm_objective",
]

class FCMResult(NamedTuple):
    """Result of [`fuzzy_cmeans`][fxspace.fuzzy_cmeans].

    **Fields:**

    - `centers`: (c, d) cluster centres V.
    - `memberships`: (n, c) fuzzy memberships U (rows sum to 1), optimal for `centers`.
    - `objective`: J_m(U, V) (scalar).
    - `num_steps`: number of Bezdek iterations run.
    - `converged`: `result == RESULTS.successful` (kept for older callers): the largest
      per-entry membership change fell below `tol` before `max_steps`, on finite data.
    - `result`: a [`RESULTS`][fxspace.RESULTS] member: `successful`, `max_steps_reached`,
      `nonfinite_input` (NaN/inf in `x` or the initial state) or `nonfinite_output`.
    - `stats`: scalar diagnostics: `max_steps`, `delta` (the last membership change)
      and `tol`.
    """

    centers: Float[Array, "c d"]
    memberships: Float[Array, "n c"]
    objective: Float[Array, ""]
    num_steps: Int[Array, ""]
    result: Any
    stats: dict[str, Array]

    @property
    def converged(self):
        """``result == RESULTS.successful`` (derived, not stored)."""
        return self.result == RESULTS.successful


def _tiny(dtype) -> float:
    # a floor on squared distances: keeps d^{-2/(m-1)} finite for points on a centre
    return float(jnp.finfo(dtype).tiny) ** 0.5 if dtype == jnp.float64 else 1e-18


def _weights(d2: Float[Array, "n c"], m: float) -> Float[Array, "n c"]:
    d2 = jnp.maximum(d2, _tiny(d2.dtype))
    if m == 2.0:
        return 1.0 / d2
    return jnp.power(d2, -1.0 / (m - 1.0))


def _memberships_and_objective(x, v, m):
    w = _weights(squared_distances(x, v), m)
    s = jnp.sum(w, axis=1, keepdims=True)
    u = w / s
    obj = jnp.sum(1.0 / s) if m == 2.0 else jnp.sum(jnp.power(s, 1.0 - m))
    return u, obj


def _centers(x, u, m, v_prev):
    um = u * u if m == 2.0 else jnp.power(u, m)
    mass = jnp.sum(um, axis=0)
    num = jnp.einsum("nc,nd->cd", um, x, precision=jax.lax.Precision.HIGHEST)
    # an empty cluster (mass underflowed to 0) keeps its previous centre
    ok = mass > 0
    return jnp.where(ok[:, None], num / jnp.where(ok, mass, 1.0)[:, None], v_prev)


@checked
def fcm_memberships(
    x: Float[Array, "n d"], centers: Float[Array, "c d"], m: float = 2.0
) -> Float[Array, "n c"]:
    """Memberships optimal for fixed centres (Bezdek's u-update)."""
    return _memberships_and_objective(jnp.asarray(x), jnp.asarray(centers), float(m))[0]


@checked
def fcm_objective(
    x: Float[Array, "n d"],
    centers: Float[Array, "c d"],
    memberships: Float[Array, "n c"],
    m: float = 2.0,
) -> Float[Array, ""]:
    """J_m(U, V) = Σ_i Σ_k u_ik^m ‖x_i − v_k‖² for arbitrary U and V."""
    d2 = squared_distances(jnp.asarray(x), jnp.asarray(centers))
    return jnp.sum(jnp.power(memberships, m) * d2)


def _fcm_loop(x, v0, u0, m, tol, max_steps, criterion="max", check_every=1, u0_free=True):
    """Bezdek iterations from (U0, V0) where U0 is the current membership estimate.

    The membership change is measured every ``check_every`` steps (the last step of each
    block); the steps in between update the centres only (V ← V(U(V))). When every block
    is whole (``max_steps`` a multiple of ``check_every`` ≥ 2, the defaults) the loop is
    `_fcm_loop_fused`, which never stores U inside the loop; else this one. ``u0_free``:
    ``U0`` is not ``U(V0)`` (memberships given by the caller).
    """
    if check_every > 1 and max_steps % check_every == 0:
        return _fcm_loop_fused(x, v0, u0, m, tol, max_steps, criterion, check_every, u0_free)

    def memb(v):
        return _memberships_and_objective(x, v, m)[0]

    def cond(state):
        _, _, _, step, delta = state
        return (step < max_steps) & (delta >= tol)

    def body(state):
        u, v, _, step, _ = state
        blk = jnp.minimum(check_every, max_steps - step)
        if check_every > 1:
            v1 = _centers(x, u, m, v)
            n_mid = jnp.maximum(blk - 2, 0)
            v1 = jax.lax.fori_loop(0, n_mid, lambda _, vv: _centers(x, memb(vv), m, vv), v1)
            long = blk >= 2
            u_prev = jnp.where(long, memb(v1), u)
            v = jnp.where(long, v1, v)
        else:
            u_prev = u
        v = _centers(x, u_prev, m, v)
        u_new, obj = _memberships_and_objective(x, v, m)
        if criterion == "max":
            delta = jnp.max(jnp.abs(u_new - u_prev))
        else:  # "fro": scikit-fuzzy's / fuzzy-c-means' rule, ‖U_t − U_{t−1}‖_F
            delta = jnp.sqrt(jnp.sum(jnp.square(u_new - u_prev)))
        return u_new, v, obj, step + blk, delta

    inf = jnp.asarray(jnp.inf, x.dtype)
    state = (u0, v0, inf, jnp.asarray(0, jnp.int32), inf)
    u, v, obj, steps, delta = jax.lax.while_loop(cond, body, state)
    # with max_steps = 0 the objective of the initial state is still reported
    u_fin, obj_fin = _memberships_and_objective(x, v, m)
    obj = jnp.where(steps == 0, obj_fin, obj)
    u = jnp.where(steps == 0, u_fin, u)
    return _fcm_result(x, v0, u0, u, v, obj, steps, delta, tol, max_steps)


def _fcm_result(x, v0, u0, u, v, obj, steps, delta, tol, max_steps) -> FCMResult:
    """The `FCMResult` of a finished loop: its `RESULTS` member and stats."""
    # a NaN/inf iterate (e.g. from non-finite data under jit) never reports convergence
    ok = jnp.isfinite(obj) & jnp.all(jnp.isfinite(v)) & jnp.all(jnp.isfinite(u))
    bad_in = ~(jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(u0)) & jnp.all(jnp.isfinite(v0)))
    result = result_from_flags(
        converged=(delta < tol) & ok, nonfinite_input=bad_in, nonfinite_output=~ok
    )
    stats = {"max_steps": jnp.asarray(max_steps, jnp.int32), "delta": delta, "tol": tol}
    # non-finite input: NaN out, never the plausible-looking initial centres
    v, u, obj = (jnp.where(bad_in, jnp.nan, a) for a in (v, u, obj))
    return FCMResult(v, u, obj, steps, result, stats)


def _weights_t(x, v, m, valid=None):
    """``(c, n)`` weights ``d_ki^{-2/(m-1)}`` and their column sums ``s`` ``(1, n)``: the
    memberships are ``w / s``. Transposed (centres × points) so that XLA fuses the
    per-point sums over the centres and the per-centre sums over the points into passes
    that never store an ``(n, c)`` array (3–5× faster per step at c = 1280, n = 2400)."""
    d2 = jnp.square(v[:, 0:1] - x[None, :, 0])
    for j in range(1, x.shape[1]):
        d2 = d2 + jnp.square(v[:, j : j + 1] - x[None, :, j])
    w = _weights(d2, m)
    if valid is not None:  # padding rows (`_fcm_padded`): no weight
        w = jnp.where(valid[:, None], w, 0.0)
    return w, jnp.sum(w, axis=0, keepdims=True)


def _next_centers(x, v, m, valid=None):
    """``V(U(V))``: one Bezdek step from centres to centres (eq. for v_k after u_ik), fused;
    an empty cluster (and a padding row) keeps its centre."""
    w, s = _weights_t(x, v, m, valid)
    um = jnp.square(w / s) if m == 2.0 else jnp.power(w / s, m)
    # one product gives Σ_i u_ik^m and Σ_i u_ik^m x_i (a broadcast x would be stored)
    ones = jnp.ones((x.shape[0], 1), x.dtype)
    mn = jnp.dot(um, jnp.concatenate([ones, x], axis=1), precision=jax.lax.Precision.HIGHEST)
    mass, num = mn[:, 0], mn[:, 1:]
    ok = mass > 0
    return jnp.where(ok[:, None], num / jnp.where(ok, mass, 1.0)[:, None], v)


def _change(x, va, vb, m, criterion, valid=None):
    """The membership change between the memberships of centres ``va`` and ``vb``
    (``criterion``: the largest entry, or the Frobenius norm) and J at ``vb``, fused."""
    wa, sa = _weights_t(x, va, m, valid)
    wb, sb = _weights_t(x, vb, m, valid)
    du = wb / sb - wa / sa
    if criterion == "max":
        delta = jnp.max(jnp.abs(du))
    else:
        delta = jnp.sqrt(jnp.sum(jnp.square(du)))
    obj = jnp.sum(1.0 / sb) if m == 2.0 else jnp.sum(jnp.power(sb, 1.0 - m))
    return delta, obj


def _fcm_loop_fused(x, v0, u0, m, tol, max_steps, criterion, check_every, u0_free,
                    valid=None):  # fmt: skip
    """`_fcm_loop` when every block is ``check_every`` ≥ 2 steps: the same iterates, carried
    as centres only. A block runs ``check_every − 1`` steps ``V ← V(U(V))`` to ``V1``, then
    ``V = V(U(V1))`` and the change ``max|U(V) − U(V1)|``. The first step is ``V(U0)``:
    from ``V0`` when ``U0 = U(V0)``; computed before the loop when ``u0_free`` (given
    memberships), the first block then running one step less. ``valid``: the real rows of
    padded centres (`_fcm_padded`)."""

    def cond(state):
        return (state[1] < max_steps) & (state[3] >= tol)

    def body(state):
        v, step, _, _ = state
        skip = (step == 0) & u0_free
        v1 = jax.lax.fori_loop(skip.astype(jnp.int32), check_every - 1,
                               lambda _, vv: _next_centers(x, vv, m, valid), v)  # fmt: skip
        v = _next_centers(x, v1, m, valid)
        delta, obj = _change(x, v1, v, m, criterion, valid)
        return v, step + check_every, obj, delta

    inf = jnp.asarray(jnp.inf, x.dtype)
    start = _centers(x, u0, m, v0) if u0_free else v0
    state = (start, jnp.asarray(0, jnp.int32), inf, inf)
    v, steps, obj, delta = jax.lax.while_loop(cond, body, state)
    v = jnp.where(steps == 0, v0, v)
    if valid is None:
        u, obj_fin = _memberships_and_objective(x, v, m)
    else:
        u, obj_fin = _memberships_padded(x, v, m, valid)
    obj = jnp.where(steps == 0, obj_fin, obj)
    return _fcm_result(x, v0, u0, u, v, obj, steps, delta, tol, max_steps)


# Small problems share compiled kernels: centres padded up this ladder while the padded
# (n, c) passes stay under the budget (well under a millisecond a step), so the FCM levels
# of a hierarchy on ~10³ frames compile 4 kernels (c ≤ 80, ≤ 320, 640, 1280), not 8
_PAD_LADDER = (80, 320, 1280, 5120)
_PAD_BUDGET = 1 << 20


def _padded_size(n: int, c: int) -> int:
    """The padded centre count of ``c`` centres on ``n`` points (``c``: no padding)."""
    for b in _PAD_LADDER:
        if b >= c:
            return b if n * b <= _PAD_BUDGET else c
    return c


def _memberships_padded(x, v, m, valid):
    """`_memberships_and_objective` of padded centres: ``(n, c_pad)``, 0 on padding rows."""
    w, s = _weights_t(x, v, m, valid)
    obj = jnp.sum(1.0 / s) if m == 2.0 else jnp.sum(jnp.power(s, 1.0 - m))
    return (w / s).T, obj


def _fcm_padded(x, v0, size: int, m, tol, max_steps: int, criterion: str, check_every: int):
    """The fused FCM from centres ``v0`` ``(c, d)`` padded to ``size`` rows (concrete
    arrays): the same iterates as without padding, one compiled kernel for every ``c`` up
    to ``size``; the result cut back to ``c`` centres."""
    c, d = v0.shape
    vp = jnp.asarray(np.concatenate([np.asarray(v0), np.zeros((size - c, d), v0.dtype)]))
    res = _fcm_padded_jit(x, vp, jnp.asarray(c, jnp.int32), m, tol, max_steps, criterion,
                          check_every)  # fmt: skip
    return res._replace(centers=jnp.asarray(np.asarray(res.centers)[:c]),
                        memberships=jnp.asarray(np.asarray(res.memberships)[:, :c]))  # fmt: skip


@partial(jax.jit, static_argnames=("m", "max_steps", "criterion", "check_every"))
def _fcm_padded_jit(x, vp, c, m, tol, max_steps, criterion, check_every):
    valid = jnp.arange(vp.shape[0]) < c
    u0 = _memberships_padded(x, vp, m, valid)[0]
    res = _fcm_loop_fused(x, vp, u0, m, tol, max_steps, criterion, check_every, False, valid)
    # a full rung (no padding rows): the memberships as the unpadded kernel forms them, so
    # c = 80, 320, … share this compile and give `_fcm_jit`'s numbers bit for bit
    u_full = _memberships_and_objective(x, res.centers, m)[0]
    return res._replace(memberships=jnp.where(c == vp.shape[0], u_full, res.memberships))


@partial(
    jax.jit, static_argnames=("n_clusters", "m", "max_steps", "n_init", "criterion", "check_every")
)
def _fcm_jit(
    x,
    n_clusters,
    m,
    tol,
    max_steps,
    n_init,
    key,
    init_centers,
    init_memberships,
    criterion,
    check_every,
):
    if init_memberships is not None:
        u0 = init_memberships / jnp.sum(init_memberships, axis=1, keepdims=True)
        v0 = jnp.zeros((n_clusters, x.shape[1]), x.dtype)
        return _fcm_loop(x, v0, u0, m, tol, max_steps, criterion, check_every)
    if init_centers is not None:
        u0 = _memberships_and_objective(x, init_centers, m)[0]
        # one centre update is implied by the memberships; start the loop from them
        return _fcm_loop(x, init_centers, u0, m, tol, max_steps, criterion, check_every, False)

    def one(k):
        v0 = kmeanspp_init(x, n_clusters, k)
        u0 = _memberships_and_objective(x, v0, m)[0]
        return _fcm_loop(x, v0, u0, m, tol, max_steps, criterion, check_every, False)

    keys = jax.random.split(key, n_init)
    runs = jax.vmap(one)(keys)
    best = jnp.argmin(jnp.where(jnp.isnan(runs.objective), jnp.inf, runs.objective))
    return jax.tree_util.tree_map(lambda a: a[best], runs)


def _check_args(x, n_clusters, m, key, tol, max_steps, n_init, init_centers, init_memberships,
                criterion, check_every):  # fmt: skip
    """`fuzzy_cmeans`'s argument checks, each naming the argument and the fix; returns
    ``(n_clusters, m, tol, init_centers, init_memberships, key)`` normalised."""
    n = x.shape[0]
    if isinstance(n_clusters, bool) or not isinstance(n_clusters, int | np.integer):
        raise FxspaceError(f"n_clusters must be an integer, got {n_clusters!r}")
    n_clusters = int(n_clusters)
    if n_clusters < 1:
        raise FxspaceError(f"n_clusters must be >= 1, got {n_clusters}")
    if n_clusters > n:
        raise FxspaceError(
            f"n_clusters={n_clusters} exceeds n_samples={n}: fuzzy c-means needs at most one "
            "centre per sample; lower n_clusters or pass more data"
        )
    if key is not None:
        check_key(key, "key")  # one key (a batch of keys: vmap over it)
    m = check_scalar(m, "m (fuzzifier)", low=1.0, low_open=True)
    tol = check_scalar(tol, "tol", low=0.0)
    if int(max_steps) < 0:
        raise FxspaceError(f"max_steps must be >= 0, got {max_steps}")
    if int(n_init) < 1:
        raise FxspaceError(f"n_init must be >= 1, got {n_init}")
    if init_centers is not None:
        init_centers = jnp.asarray(init_centers, x.dtype)
        if init_centers.shape != (n_clusters, x.shape[1]):
            raise FxspaceError(
                f"init_centers must have shape (n_clusters, n_features) = "
                f"{(n_clusters, x.shape[1])}, got {init_centers.shape}"
            )
    if init_memberships is not None:
        init_memberships = jnp.asarray(init_memberships, x.dtype)
        if init_memberships.shape != (n, n_clusters):
            raise FxspaceError(
                f"init_memberships must have shape (n_samples, n_clusters) = "
                f"{(n, n_clusters)}, got {init_memberships.shape}"
            )
    if criterion not in ("max", "fro"):
        raise FxspaceError(f"criterion must be 'max' or 'fro', got {criterion!r}")
    if int(check_every) < 1:
        raise FxspaceError(f"check_every must be >= 1, got {check_every}")
    if init_centers is None and init_memberships is None and key is None:
        raise FxspaceError("key is required for k-means++ seeding: pass key=jax.random.key(0)")
    if key is None:
        key = jax.random.PRNGKey(0)
    return n_clusters, m, tol, init_centers, init_memberships, key


@checked
def fuzzy_cmeans(
    x: Float[Array, "n d"],
    n_clusters: int,
    m: float = 2.0,
    *,
    key: Array | None = None,
    tol: float = 1e-4,
    max_steps: int = 300,
    n_init: int = 1,
    init_centers: Float[Array, "c d"] | None = None,
    init_memberships: Float[Array, "n c"] | None = None,
    criterion: Literal["max", "fro"] = "max",
    check_every: int = 4,
    throw: bool = False,
) -> FCMResult:
    """Fuzzy c-means with full memberships (Bezdek's alternating updates) as one jitted
    while-loop: the implementation behind `fxspace.cluster.fuzzy_cmeans` (`._fcm_front`,
    where the arguments, returns and an example are documented) when no ``nearest`` is
    given."""
    x = as_float_array(x, "x", axes=("n_samples", "n_features"), finite="allow")
    if throw and not _is_tracer(x):
        check_finite(x, "x")  # names where the NaN/inf are
    n_clusters, m, tol, init_centers, init_memberships, key = _check_args(
        x, n_clusters, m, key, tol, max_steps, n_init, init_centers, init_memberships,
        criterion, check_every,
    )  # fmt: skip
    size = _padded_size(x.shape[0], n_clusters)
    rung = size in _PAD_LADDER and x.shape[0] * size <= _PAD_BUDGET  # c = 80, 320, …: padded too
    if ((size > n_clusters or rung) and init_centers is not None and init_memberships is None
            and check_every > 1 and max_steps % check_every == 0
            and not _is_tracer(x) and not _is_tracer(init_centers)):  # fmt: skip
        res = _fcm_padded(x, init_centers, size, m, jnp.asarray(tol, x.dtype), int(max_steps),
                          criterion, int(check_every))  # fmt: skip
        return check_result(res.result, throw, "fuzzy_cmeans", res)
    res = _fcm_jit(
        x,
        n_clusters,
        m,
        jnp.asarray(tol, x.dtype),
        int(max_steps),
        int(n_init),
        key,
        init_centers,
        init_memberships,
        criterion,
        int(check_every),
    )
    return check_result(res.result, throw, "fuzzy_cmeans", res)


# the old private name, kept for callers inside this subpackage
_sq_dists = squared_distances
