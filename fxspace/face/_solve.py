"""Expression weights and head motion from bound markers: bounded least squares with a
temporal term, all frames at once.

With the markers in the rig's frame and units (the binding's similarity), frame ``t``'s
marker ``m`` is modelled as

    y_tm ≈ R_t (b_m + Σ_k w_tk a_km) + τ_t,     0 ≤ w_tk ≤ 1,

``b_m`` the bound point on the neutral, ``a_km`` shape ``k``'s delta there, ``(R_t, τ_t)``
the head's rigid motion. `solve_weights` minimises

    Σ_t Σ_m v_tm ‖R_t (b_m + A_m w_t) + τ_t − y_tm‖² + λ Σ_t ‖w_t − w_{t−1}‖² + μ ‖w‖²

(``v_tm`` = 0 for a missing marker, 1 otherwise) by alternation: the rigid motion per
frame in closed form (Kabsch, weighted by ``v``), then the weights of every frame at
once by accelerated projected gradient (FISTA with the box projection; the temporal
term couples neighbouring frames), each round warm-started from the last. Jitted, every
frame in one batch (the frame axis is a batch axis, as ``vmap`` makes it), fixed
iteration counts so reverse-mode ``jax.grad`` runs through the whole solve.
``λ = temporal · tr(H)/K`` and ``μ = ridge · tr(H)/K`` scale with the data term
(``H = Σ_m A_mᵀA_m``), so the defaults hold for any rig's units; the step is
``1/(λmax(H) + 4λ + μ)`` (a frame with markers missing has ``H_t ≤ H``).

The result per frame says whether the **fit is good**, not only whether the iteration
ended: ``RESULTS.successful`` when the Frank–Wolfe gap (an upper bound on the
objective's distance from its minimum, by convexity) is below ``tol`` times the frame's
data term *and* the model fits the markers — the frame's RMS residual is at most
``fit_tol`` times the bound face's size (`Binding.size`, the RMS radius of the neutral
markers; on the AnimFace takes and the ICT head the worst frame is at 0.04) and no
marker is farther than ``outlier_tol`` times that size from the model (worst real
marker 0.11); ``poor_fit`` when either fails (``.outliers`` names the markers,
``.notes`` says which frames and markers, and which markers look swapped);
``max_steps_reached`` when the fit is good but the gap is not yet small;
``nonfinite_input`` for a frame with fewer than 3 markers seen (its weights and motion
NaN).

Before solving, the take is checked against the binding: with names (``names=`` or a
`MarkerSequence`) the markers are matched to the binding's by name (another order is
re-ordered; a missing or unknown marker is refused, with near matches); with units on
both sides a take in other units is converted; and a take whose size disagrees with the
neutral frame it was bound to by more than 2× (bound in mm, solved in m or cm) is
refused with the factor and the fix. Without names, markers in another order (or two
swapped) do not fit the bound face: those frames are ``poor_fit`` and ``.notes`` names
the markers that sit where others belong.

Example:

```python
s = fx.face.solve_weights(rig, binding, take.positions)   # .weights (T, K), .residual (T, M)
s0 = fx.face.solve_weights(rig, binding, take.positions, expressions=False)  # rigid only
```
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from optax.projections import projection_box

from fxspace.errors import FxspaceError
from fxspace.face._bind import Binding
from fxspace.face._rig import Rig
from fxspace.face._solve_judge import _judge, _notes, _retry_without_worst
from fxspace.face._solve_take import (
    _check_numbers,
    _check_size,
    _convert_units,
    _size_ratio,
    _take_markers,
)
from fxspace.results import RESULTS, check_result, result_from_flags, where_result
from fxspace.rigid import fit_similarity

__all__ = ["FaceSolve", "solve_weights", "kabsch"]


class FaceSolve(NamedTuple):
    """Result of `solve_weights`.

    ``weights`` ``(T, K)`` in ``[0, 1]`` (named by ``names``); ``rotation`` ``(T, 3, 3)``
    and ``translation`` ``(T, 3)``: the head's motion in the rig's frame; ``residual``
    ``(T, M)``: each marker's distance from the model, in the capture's units (NaN where
    the marker is missing); ``result`` ``(T,)``: `fxspace.RESULTS` per frame;
    ``num_steps`` ``(T,)``: projected-gradient steps until the frame first met ``tol``
    (``max_steps`` when it never did; a warm start, ``init``, needs fewer); ``stats``:
    ``max_steps``, the final relative Frank–Wolfe gap per frame (``"optimality"``: a
    bound on how far the objective is above its minimum), the objective
    (``"objective"``), the per-frame RMS residual in the capture's units (``"rms"``),
    relative to the bound face's size (``"fit"``, judged against ``fit_tol``) and the
    frame's size relative to the neutral's (``"size_ratio"``); ``outliers`` ``(T, M)``:
    the markers farther than ``outlier_tol`` × the face's size from the model;
    ``notes``: one line per problem, naming the frames and markers (empty when every
    frame is ``successful``).
    """

    weights: jax.Array
    rotation: jax.Array
    translation: jax.Array
    residual: jax.Array
    result: object
    num_steps: jax.Array
    stats: dict
    names: tuple[str, ...] = ()
    outliers: jax.Array | None = None
    notes: tuple[str, ...] = ()

    @property
    def converged(self) -> jax.Array:
        """``result == RESULTS.successful`` per frame (derived, not stored)."""
        return self.result == RESULTS.successful

    @property
    def bad_frames(self) -> np.ndarray:
        """Indices of the frames whose result is not ``successful``."""
        return np.flatnonzero(~np.atleast_1d(np.asarray(self.converged)))


def kabsch(P, Y, v):
    """Weighted rigid fit ``Y ≈ R P + τ`` per frame: ``P``, ``Y`` ``(T, M, 3)``, weights
    ``v`` ``(T, M)``; returns ``R`` ``(T, 3, 3)`` (``det R = +1``) and ``τ`` ``(T, 3)``.
    `fxspace.rigid.fit_similarity` with ``scale=False``, kept under its name here."""
    R, _, t = fit_similarity(jnp.asarray(P), jnp.asarray(Y), jnp.asarray(v), scale=False)
    return R, t


def _laplacian(w):
    """``L w`` of the path graph over frames (the gradient of ½ Σ ‖w_t − w_{t−1}‖²)."""
    d = jnp.diff(w, axis=0)
    z = jnp.zeros_like(w[:1])
    return jnp.concatenate([z, d]) - jnp.concatenate([d, z])


@partial(jax.jit, static_argnames=("expressions", "outer", "inner", "complete"))
def _solve(B, A, Y, v, lam, mu, tol, w0, expressions, outer, inner, complete):
    T, K = Y.shape[0], A.shape[0]
    Af = A.reshape(K, -1)  # (K, 3M)
    Hf = Af @ Af.T  # Σ_m A_mᵀA_m: every frame's H_t is below it (markers only drop out)
    scale = jnp.trace(Hf) / K
    lam_, mu_ = lam * scale, mu * scale
    eye = jnp.eye(K, dtype=Y.dtype)
    # the gradient's Lipschitz constant: λmax(H) + 4λ (the path Laplacian) + μ
    lip = jnp.linalg.eigvalsh(Hf)[-1] + 4.0 * lam_ + mu_ + 1e-30
    lo, hi = jnp.zeros((), Y.dtype), jnp.ones((), Y.dtype)
    vm = jnp.repeat(v, 3, axis=1)  # (T, 3M)

    def hess(w):  # H_t w_t for every frame: one product when no marker is missing
        if complete:
            return w @ (Hf + mu_ * eye)
        return ((w @ Af) * vm) @ Af.T + mu_ * w

    def grad(w, b):
        return hess(w) - b + lam_ * _laplacian(w)

    def fista(w, b):
        def body(_, c):
            x, yk, tk = c
            xn = projection_box(yk - grad(yk, b) / lip, lo, hi)
            tn = 0.5 * (1.0 + jnp.sqrt(1.0 + 4.0 * tk * tk))
            yn = xn + ((tk - 1.0) / tn) * (xn - x)
            return xn, yn, tn

        x, _, _ = jax.lax.fori_loop(0, inner, body, (w, w, jnp.ones((), Y.dtype)))
        return x

    def rigid(w):
        return kabsch(B[None] + (w @ Af).reshape(T, -1, 3), Y, v)

    def rhs(R, tau):
        Z = jnp.einsum("tmc,tcd->tmd", Y - tau[:, None], R)  # Rᵀ (y − τ)
        return (vm * (Z - B[None]).reshape(T, -1)) @ Af.T

    def gap(w, R, tau, b):
        # the Frank–Wolfe gap of the box QP, max over the box of gᵀ(w − u): an upper
        # bound on how far the objective is above its minimum (convexity), per frame,
        # relative to the frame's data term at w = 0 (½ Σ_m v ‖Rᵀ(y − τ) − b_m‖²)
        g = grad(w, b)
        Z = jnp.einsum("tmc,tcd->tmd", Y - tau[:, None], R) - B[None]
        energy = 0.5 * jnp.sum(v[..., None] * Z * Z, axis=(1, 2))
        return jnp.sum(g * w - jnp.minimum(g, 0.0), axis=1) / (energy + scale)

    def round_(k, c):
        w, _, _, done = c
        R, tau = rigid(w)
        b = rhs(R, tau)
        # the rounds a frame needed: the first round that starts within tol
        done = jnp.where((done < 0) & (gap(w, R, tau, b) <= tol), k, done)
        w = fista(w, b) if expressions else w
        return w, R, tau, done

    R0, t0 = rigid(w0)
    done0 = jnp.full((T,), -1, jnp.int32)
    w, R, tau, done = jax.lax.fori_loop(0, outer, round_, (w0, R0, t0, done0))
    R, tau = rigid(w)
    b = rhs(R, tau)
    opt = gap(w, R, tau, b)
    rounds = jnp.where(done >= 0, done, outer)
    model = jnp.einsum("tij,tmj->tmi", R, B[None] + (w @ Af).reshape(T, -1, 3))
    r = jnp.linalg.norm(model + tau[:, None] - Y, axis=-1)
    obj = jnp.sum(v * r * r) + lam_ * jnp.sum(jnp.diff(w, axis=0) ** 2) + mu_ * jnp.sum(w * w)
    opt = opt if expressions else jnp.zeros_like(opt)
    rounds = rounds if expressions else jnp.full((T,), outer, jnp.int32)
    return w, R, tau, r, opt, obj, rounds * inner


def solve_weights(
    rig: Rig,
    binding: Binding,
    markers,
    *,
    expressions: bool = True,
    temporal: float = 0.02,
    ridge: float = 1e-4,
    outer: int = 20,
    inner: int = 30,
    tol: float = 1e-2,
    init=None,
    names=None,
    units: str | None = None,
    fit_tol: float = 0.08,
    outlier_tol: float = 0.25,
    throw: bool = False,
) -> FaceSolve:
    """Per-frame expression weights in ``[0, 1]`` and the head's rigid motion from the
    bound markers (see the module docstring).

    **Arguments:** `rig`, `binding` (`bind_markers`); `markers` ``(T, M, 3)`` (or one
    frame ``(M, 3)``) in the capture's frame and units, NaN where a marker is missing,
    or a `fxspace.io.MarkerSequence` (its names and units are used); `expressions`:
    ``False`` solves the rigid motion alone (weights 0: the baseline the residual is
    compared with); `temporal`: the smoothness weight λ (relative to the data term; 0 =
    frames independent); `ridge`: μ, a small pull to 0 for shapes the markers cannot
    see; `outer`, `inner`: alternation rounds and projected-gradient steps per round
    (the rigid motion and the weights trade off slowly: many short rounds beat few long
    ones; on the AnimFace jaw take 20 × 30 reaches the objective of 20 × 1000 within
    0.2 %); `tol`: the Frank–Wolfe gap a frame must reach, relative to its data term
    (the objective provably within that fraction of its minimum at the solved head
    motion); `init` ``(T, K)``: starting weights (default 0; the unedited solve's
    weights for an edited take: a warm start); `names` (``M``): the take's marker names,
    matched to the binding's (re-ordered when only the order differs); `units`: the
    take's length unit (converted to the binding's when both are known); `fit_tol`,
    `outlier_tol`: a frame whose RMS residual exceeds ``fit_tol`` × the bound face's
    size, or with a marker farther than ``outlier_tol`` × that size from the model, is
    ``poor_fit``; `throw`: raise when a frame is not ``successful``.

    **Returns:** a `FaceSolve`.
    """
    X, single, units = _take_markers(rig, binding, markers, names, units)
    _check_numbers(temporal=temporal, ridge=ridge, tol=tol, fit_tol=fit_tol,
                   outlier_tol=outlier_tol, outer=outer, inner=inner)  # fmt: skip
    X = _convert_units(X, units, binding.units)
    seen = np.all(np.isfinite(X), axis=-1)
    dtype = jnp.asarray(0.0).dtype
    Yh = np.asarray(binding.to_rig(np.where(seen[..., None], X, 0.0)), np.float64)
    size = binding.size
    ratio = _size_ratio(Yh, seen, np.asarray(binding.points, np.float64))
    _check_size(ratio, units, binding.units)
    Y = jnp.asarray(Yh, dtype)
    v = jnp.asarray(seen, dtype)
    K = rig.num_shapes
    w0 = jnp.zeros((len(X), K), dtype) if init is None else jnp.asarray(init, dtype)
    if w0.shape != (len(X), K) or not bool(jnp.all(jnp.isfinite(w0))):
        raise FxspaceError(
            f"init must be finite weights of shape ({len(X)}, {K}); got {tuple(w0.shape)} "
            "(fill the unsolved frames of a previous solve, e.g. with 0)"
        )
    w0 = jnp.clip(w0, 0.0, 1.0)
    B = jnp.asarray(binding.points, dtype)
    A = jnp.asarray(binding.basis, dtype)
    complete = bool(seen.all())
    w, R, tau, r, opt, obj, steps = _solve(
        B, A, Y, v, temporal, ridge, tol, w0, bool(expressions), int(outer), int(inner), complete
    )
    few = jnp.asarray(seen.sum(axis=1) < 3)
    ratio_j = jnp.asarray(ratio, dtype)
    rr = jnp.where(jnp.asarray(seen) & ~few[:, None], r, jnp.nan)  # rig units
    rms, fit, outl, poor = _judge(rr, seen, size, ratio_j, fit_tol, outlier_tol)
    state = (w, R, tau, rr, opt, steps, rms, fit, outl, poor)
    state, dropped = _retry_without_worst(
        lambda v2, w_init: _solve(B, A, Y, v2, temporal, ridge, tol, w_init, bool(expressions),
                                  int(outer), int(inner), False),
        state, seen, few, dtype, size, ratio_j, fit_tol, outlier_tol,
    )  # fmt: skip
    w, R, tau, rr, opt, steps, rms, fit, outl, poor = state
    nan = jnp.nan
    w = jnp.where(few[:, None], nan, w)
    R = jnp.where(few[:, None, None], nan, R)
    tau = jnp.where(few[:, None], nan, tau)
    r = rr / binding.scale
    ok = (opt <= tol) & jnp.all(jnp.isfinite(w), axis=1)
    result = result_from_flags(converged=ok, nonfinite_input=few)
    result = where_result(poor & ~few, RESULTS.poor_fit, result)
    result = where_result(~few & ~jnp.all(jnp.isfinite(r) | ~jnp.asarray(seen), axis=1),
                          RESULTS.nonfinite_output, result)  # fmt: skip
    stats = {"max_steps": jnp.asarray(outer * inner), "optimality": opt, "objective": obj,
             "rms": rms / binding.scale, "fit": fit, "size_ratio": ratio_j}  # fmt: skip
    notes = _notes(binding, np.asarray(fit), np.asarray(outl), np.asarray(ratio), np.asarray(few),
                   fit_tol, outlier_tol, Yh, seen, np.asarray(w), np.asarray(R),
                   np.asarray(tau), A, np.asarray(rr), dropped)  # fmt: skip
    out = FaceSolve(w, R, tau, r, result, steps, stats, rig.names, outl, notes)
    if single:
        out = jax.tree_util.tree_map(lambda a: a[0] if getattr(a, "ndim", 0) else a, out)
    return check_result(out.result, throw, "solve_weights", out)
