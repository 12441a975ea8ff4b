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


def _take_markers(rig, binding, markers, names, units):
    """``(X, single, units)``: the markers as ``(T, M, 3)`` float64 in the binding's
    marker order (``single`` when one frame was passed), after checking the rig and the
    binding; a `MarkerSequence`'s names and units fill in ``names`` and ``units``."""
    if not isinstance(rig, Rig) or not isinstance(binding, Binding):
        raise FxspaceError("pass a fx.face.Rig and the fx.face.Binding from bind_markers")
    if hasattr(markers, "positions") and hasattr(markers, "names"):  # a MarkerSequence
        names = markers.names if names is None else names
        units = getattr(markers, "units", None) if units is None else units
        markers = markers.positions
    X = np.asarray(markers, np.float64)
    single = X.ndim == 2
    X = X[None] if single else X
    M = len(binding.names)
    if names is not None:
        X = _by_name(X, names, binding.names)
    if X.ndim != 3 or X.shape[1:] != (M, 3) or len(X) < 1:
        raise FxspaceError(f"markers must be (frames, {M}, 3) for this binding; got {X.shape}")
    if binding.basis.shape[0] != rig.num_shapes:
        raise FxspaceError("binding was made for another rig (shape count differs); bind again")
    return X, single, units


def _check_numbers(*, temporal, ridge, tol, fit_tol, outlier_tol, outer, inner) -> None:
    """Refuse a non-finite or negative tolerance or weight, and iteration counts that are
    not integers >= 1."""
    checks = (("temporal", temporal, 0.0), ("ridge", ridge, 0.0), ("tol", tol, 0.0),
              ("fit_tol", fit_tol, 0.0), ("outlier_tol", outlier_tol, 0.0))  # fmt: skip
    for name, val, low in checks:
        if not (np.isfinite(val) and val >= low):
            raise FxspaceError(f"{name} must be a finite number >= {low}; got {val!r}")
    for name, val in (("outer", outer), ("inner", inner)):
        if not isinstance(val, (int, np.integer)) or val < 1:
            raise FxspaceError(f"{name} must be an integer >= 1; got {val!r}")


def _retry_without_worst(solve, state, seen, few, dtype, size, ratio_j, fit_tol, outlier_tol):
    """One marker far off (a glitch) drags the whole frame's fit: leave each poor frame's
    worst marker out and solve again (``solve(v, w0)``); keep that where the rest then
    fits. ``state`` is ``(w, R, tau, rr, opt, steps, rms, fit, outl, poor)``; returns the
    updated state and the ``(T, M)`` mask of markers left out."""
    w, R, tau, rr, opt, steps, rms, fit, outl, poor = state
    dropped = np.zeros(seen.shape, bool)
    bad = np.flatnonzero(np.asarray(poor & ~few) & (seen.sum(axis=1) >= 5))
    if len(bad):
        worst = np.argmax(np.nan_to_num(np.asarray(rr)[bad], nan=-1.0), axis=1)
        drop = np.zeros(seen.shape, bool)
        drop[bad, worst] = True
        v2 = jnp.asarray(seen & ~drop, dtype)
        w2, R2, tau2, r2, opt2, obj2, steps2 = solve(v2, w)
        rr2 = jnp.where(jnp.asarray(seen) & ~few[:, None], r2, jnp.nan)
        kept = jnp.where(jnp.asarray(drop), jnp.nan, rr2)
        _, _, outl2, poor2 = _judge(kept, seen & ~drop, size, ratio_j, fit_tol, outlier_tol)
        take = np.zeros(len(seen), bool)
        take[bad] = ~np.asarray(poor2)[bad]
        if take.any():
            t = jnp.asarray(take)
            w, R, tau = (jnp.where(t[:, None], w2, w), jnp.where(t[:, None, None], R2, R),
                         jnp.where(t[:, None], tau2, tau))  # fmt: skip
            rr = jnp.where(t[:, None], rr2, rr)
            opt = jnp.where(t, opt2, opt)
            steps = jnp.where(t, steps + steps2, steps)
            rms, fit, outl, poor = _judge(jnp.where(jnp.asarray(drop), jnp.nan, rr), seen & ~drop,
                                          size, ratio_j, fit_tol, outlier_tol)  # fmt: skip
            dropped = drop & take[:, None]
            outl = outl | jnp.asarray(dropped)
            poor = poor | t
    return (w, R, tau, rr, opt, steps, rms, fit, outl, poor), dropped


def _judge(rr, seen, size: float, ratio, fit_tol: float, outlier_tol: float):
    """``(rms, fit, outliers, poor)`` of residuals ``rr`` ``(T, M)`` in rig units (NaN
    where not used) against the bound face's ``size``."""
    vs = jnp.asarray(seen, rr.dtype)
    rms = jnp.sqrt(jnp.nansum(rr * rr, axis=1) / jnp.maximum(vs.sum(axis=1), 1.0))
    fit = rms / size
    outl = jnp.nan_to_num(rr, nan=0.0) > outlier_tol * size
    off = (ratio < 0.67) | (ratio > 1.5)
    return rms, fit, outl, (fit > fit_tol) | jnp.any(outl, axis=1) | off


def _near(name: str, options) -> list[str]:
    import difflib

    low = {str(o).lower(): str(o) for o in options}
    hits = difflib.get_close_matches(name.lower(), list(low), n=3, cutoff=0.6)
    return [low[h] for h in hits]


def _by_name(X: np.ndarray, names, bound: tuple[str, ...]) -> np.ndarray:
    """The take's markers in the binding's order, matched by name."""
    names = tuple(str(n) for n in names)
    if X.ndim != 3 or X.shape[1] != len(names):
        raise FxspaceError(f"names must give one name per marker ({X.shape[1]}); got {len(names)}")
    from fxspace.face._bind import _check_unique

    _check_unique(names)
    pos = {n: i for i, n in enumerate(names)}
    missing = [n for n in bound if n not in pos]
    extra = [n for n in names if n not in set(bound)]
    if missing or extra:
        hint = "; ".join(f"{n!r}: near {_near(n, names)}" for n in missing[:3] if _near(n, names))
        raise FxspaceError(
            f"the take's markers are not the binding's: missing {missing[:5]}, unknown "
            f"{extra[:5]}" + (f" ({hint})" if hint else "")
            + "; rename them, or bind this take (fx.face.bind_markers)"
        )
    return X[:, [pos[n] for n in bound]]


def _convert_units(X: np.ndarray, units, bound_units) -> np.ndarray:
    from fxspace.face._bind import _units_arg
    from fxspace.io import UNIT_SCALES

    try:
        u = _units_arg(units)
    except FxspaceError:
        u = None  # an unknown label: the size check below decides
    if u is None or bound_units is None or u == bound_units:
        return X
    return X * (UNIT_SCALES[u] / UNIT_SCALES[bound_units])


def _size_ratio(Y: np.ndarray, seen: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per frame, the RMS radius of the seen markers over the neutral's (same markers):
    1 for a take at the binding's scale, 0.001 for a take in m bound in mm."""
    v = seen.astype(np.float64)[..., None]
    n = np.maximum(v.sum(axis=1), 1.0)
    cy = (v * Y).sum(axis=1) / n
    cp = (v * P[None]).sum(axis=1) / n
    ry = (v * (Y - cy[:, None]) ** 2).sum(axis=(1, 2))
    rp = (v * (P[None] - cp[:, None]) ** 2).sum(axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.sqrt(ry / rp)
    return np.where(seen.sum(axis=1) >= 3, out, np.nan)


def _check_size(ratio: np.ndarray, units, bound_units) -> None:
    """Refuse a take whose size is not the neutral frame's (another unit)."""
    good = ratio[np.isfinite(ratio)]
    if not len(good):
        return
    med = float(np.median(good))
    if 0.5 <= med <= 2.0:
        return
    guess = {1000.0: "mm → m", 100.0: "cm → m", 10.0: "mm → cm", 25.4: "mm → in",
             304.8: "mm → ft", 2.54: "cm → in", 30.48: "cm → ft", 3.28084: "ft → m"}  # fmt: skip
    f = 1.0 / med if med < 1 else med
    best = min(guess, key=lambda g: abs(np.log(f / g)))
    a, b = guess[best].split(" → ")
    like = (f"bound in {a}, solved in {b}" if med < 1 else f"bound in {b}, solved in {a}")
    said = f"; the take says units={units!r}, the binding {bound_units!r}" if units else ""
    raise FxspaceError(
        f"the take is {med:.3g}× the size of the neutral frame it was bound to (like "
        f"{like}){said}: solve in the binding's units (MarkerSequence.to_units), or pass "
        "units= to bind_markers and solve_weights so the take is converted"
    )


def _notes(b: Binding, fit, outl, ratio, few, fit_tol, outlier_tol, Y, seen, w, R, tau,
           A, rr, dropped) -> tuple[str, ...]:  # fmt: skip
    """One line per problem: the poor frames and the outlying markers, by name, and the
    markers that sit where another marker belongs (swapped or re-ordered)."""

    def frames(idx) -> str:
        idx = list(map(int, idx))
        return ", ".join(map(str, idx[:8])) + (f" … ({len(idx)} in all)" if len(idx) > 8 else "")

    notes = []
    big = np.flatnonzero((fit > fit_tol) & ~few)
    if len(big):
        notes.append(
            f"frames {frames(big)}: RMS residual up to {float(np.nanmax(fit[big])):.3g}× the "
            f"face's size (fit_tol {fit_tol:g})"
        )
    off = np.flatnonzero(((ratio < 0.67) | (ratio > 1.5)) & ~few)
    if len(off):
        notes.append(f"frames {frames(off)}: the markers' spread is {float(ratio[off[0]]):.3g}× "
                     "the neutral frame's (another unit, or not this face)")  # fmt: skip
    for t, m in zip(*np.nonzero(dropped), strict=True):
        notes.append(f"frame {int(t)}: marker {b.names[m]!r} is {rr[t, m] / b.scale:.4g} (capture "
                     f"units, {rr[t, m] / b.size:.3g}× the face's size) off the model: left "
                     "out of that frame's solve")  # fmt: skip
    worst = np.nanmax(np.where(outl, rr, np.nan), axis=0, initial=-np.inf)
    worst = np.where(outl.any(axis=0), worst, -np.inf)
    for m in np.argsort(-worst)[: min(5, int(outl.any(axis=0).sum()))]:
        notes.append(f"marker {b.names[m]!r} farther than {outlier_tol:g}× the face's size "
                     f"from the model in frames {frames(np.flatnonzero(outl[:, m]))}")  # fmt: skip
    if outl.any():  # which bound point each outlying marker sits at: swapped markers
        Af = np.asarray(A, np.float64).reshape(len(A), -1)
        P = np.asarray(b.points, np.float64)
        pairs: dict[tuple[int, int], int] = {}
        for t in np.flatnonzero(outl.any(axis=1) & ~few)[:200]:
            model = (P + (np.nan_to_num(w[t]) @ Af).reshape(-1, 3)) @ R[t].T + tau[t]
            for m in np.flatnonzero(outl[t]):
                d = np.linalg.norm(model - Y[t, m], axis=1)
                j = int(np.argmin(d))
                if j != m and d[j] < 0.5 * d[m]:  # nearer another's place than its own
                    pairs[(int(m), j)] = pairs.get((int(m), j), 0) + 1
        for (m, j), n in sorted(pairs.items(), key=lambda kv: -kv[1])[:5]:
            notes.append(f"marker {b.names[m]!r} sits where {b.names[j]!r} belongs in {n} "
                         "frame(s): swapped or re-ordered markers? pass names= to match by "
                         "name")  # fmt: skip
    return tuple(notes)
