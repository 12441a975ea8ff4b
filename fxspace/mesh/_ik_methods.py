"""The mesh-IK solver objects (`fxspace.mesh.LevenbergMarquardt`, `BFGS`, `Adam`,
`OptimistixLM`, `OptimistixGaussNewton`): frozen, hashable (static under ``jit``), each
with the ``init / step / terminate / postprocess`` that `_iterate` drives, and those
steps (Levenberg–Marquardt with Nielsen's damping update, BFGS with a backtracking Armijo
line search, optax Adam, optimistix least squares).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._validate import check_choice, check_int, check_scalar
from fxspace.mesh._ik_constraints import constraint_residuals
from fxspace.mesh._ik_gradients import GRADIENTS
from fxspace.mesh._ik_problem import _diagonal, _flat, _ftol, _Outcome, _Problem

__all__ = [
    "LevenbergMarquardt",
    "BFGS",
    "Adam",
    "OptimistixLM",
    "OptimistixGaussNewton",
    "Solver",
]


_LM_DOWN = 0.2


def _check_common(obj) -> None:
    for name in ("rtol", "atol"):
        if hasattr(obj, name):
            check_scalar(getattr(obj, name), name, low=0.0)
    check_int(obj.max_steps, "max_steps", low=1)
    if hasattr(obj, "gradient"):
        check_choice(obj.gradient, "gradient", GRADIENTS)


@dataclasses.dataclass(frozen=True)
class LevenbergMarquardt:
    """Levenberg–Marquardt on the analytic Jacobian (the default solver).

    **Fields:** `rtol`: stop when an accepted step lowers the objective by less than
    ``rtol · F``; `atol`: stop when the RMS marker residual is below ``atol ×
    length_scale``; `max_steps`: iteration bound; `xtol`: stop when an accepted step
    moves no coordinate by more than `xtol` (radians, or fractions of ``length_scale`` for
    the translation; 0 = off, the default). Tracking near a non-zero-residual minimum,
    ``xtol = 1e-4`` stops the Gauss–Newton tail that no longer changes the pose visibly;
    `tau`: the initial damping ``μ₀ = tau · max diag(JᵀJ)``; ``None`` (the default)
    picks it from the start: ``1e-6`` when the initial RMS marker residual is below 1 %
    of ``length_scale`` (a warm start, close to the answer: Gauss–Newton steps at once),
    else ``1e-3`` (Nielsen's usual value). Measured on CesiumMan (120 markers, rtol 1e-3):
    tracking 300 frames warm-started, ``1e-6`` takes 3.6 iterations per frame against 7.4
    for ``1e-3`` at the same vertex error (3.38e-4); from rest, ``1e-6`` fails on some
    marker sets (a random view, 40 frames: 62 % converged vs 100 %, twice the vertex
    error; measured with Nielsen's damping floor 1/3, see `_solve_lm`), hence the rule.
    """

    rtol: float = 1e-6
    atol: float = 1e-7
    max_steps: int = 50
    xtol: float = 0.0
    tau: float | None = None

    def __post_init__(self):
        _check_common(self)
        check_scalar(self.xtol, "xtol", low=0.0)
        if self.tau is not None:
            check_scalar(self.tau, "tau", low=0.0, low_open=True)

    def init(self, pb, skip):
        return _lm_init(pb, self, skip)

    def step(self, pb, state):
        return _lm_step(pb, self, state)

    def terminate(self, state):
        return state[6]

    def postprocess(self, pb, state, steps):
        return _lm_postprocess(pb, self, state, steps)


@dataclasses.dataclass(frozen=True)
class BFGS:
    """BFGS on the chosen gradient form (`gradient`: ``"factored"`` eq. (13), ``"naive"``
    eq. (9), ``"autodiff"``); `rtol`, `atol`, `max_steps` as `LevenbergMarquardt`."""

    rtol: float = 1e-6
    atol: float = 1e-7
    max_steps: int = 200
    gradient: str = "factored"

    def __post_init__(self):
        _check_common(self)

    def init(self, pb, skip):
        return _bfgs_init(pb, self, skip)

    def step(self, pb, state):
        return _bfgs_step(pb, self, state)

    def terminate(self, state):
        return state[5]

    def postprocess(self, pb, state, steps):
        return _bfgs_postprocess(pb, self, state, steps)


@dataclasses.dataclass(frozen=True)
class Adam:
    """optax Adam on the chosen gradient form; `learning_rate` in radians (the
    translation is scaled by the mesh size); stops when the RMS marker residual is below
    ``atol × length_scale`` or after `max_steps`."""

    learning_rate: float = 0.02
    atol: float = 1e-7
    max_steps: int = 50
    gradient: str = "factored"

    def __post_init__(self):
        _check_common(self)
        check_scalar(self.learning_rate, "learning_rate", low=0.0, low_open=True)

    def init(self, pb, skip):
        return _adam_init(pb, self, skip)

    def step(self, pb, state):
        return _adam_step(pb, self, state)

    def terminate(self, state):
        return state[2] | state[3]

    def postprocess(self, pb, state, steps):
        return _adam_postprocess(pb, self, state, steps)


class _Optimistix:
    """The loop's methods for optimistix's solvers: optimistix runs its own ``iterate`` in
    ``init``; the outer loop has nothing left to do (``terminate`` is true at once)."""

    def init(self, pb, skip):
        return _optx_init(pb, self, skip)

    def step(self, pb, state):
        return state

    def terminate(self, state):
        return jnp.asarray(True)

    def postprocess(self, pb, state, steps):
        return _optx_postprocess(pb, self, state, steps)


@dataclasses.dataclass(frozen=True)
class OptimistixLM(_Optimistix):
    """optimistix's Levenberg–Marquardt on the residual vector (autodiff Jacobian)."""

    rtol: float = 1e-6
    atol: float = 1e-7
    max_steps: int = 50

    def __post_init__(self):
        _check_common(self)


@dataclasses.dataclass(frozen=True)
class OptimistixGaussNewton(_Optimistix):
    """optimistix's Gauss–Newton on the residual vector (autodiff Jacobian)."""

    rtol: float = 1e-6
    atol: float = 1e-7
    max_steps: int = 50

    def __post_init__(self):
        _check_common(self)


Solver = LevenbergMarquardt | BFGS | Adam | OptimistixLM | OptimistixGaussNewton


# --- Levenberg–Marquardt ---------------------------------------------------------------


def _lm_init(pb: _Problem, solver: LevenbergMarquardt, skip):
    abs_obj = pb.abs_tolerance(solver.atol)
    z0 = _flat(pb.init) / pb.sv
    obj0, g0, h0 = pb.normal_equations(z0)
    hmax = jnp.maximum(jnp.max(_diagonal(h0)), jnp.finfo(z0.dtype).tiny)
    done0 = (obj0 <= abs_obj) & ~skip
    false = jnp.asarray(False)
    if solver.tau is None:  # warm start (RMS residual < 1 % of L): Gauss–Newton at once
        near = obj0 < (0.01 * pb.model.length_scale) ** 2 * pb.targets.shape[0]
        tau = jnp.where(near, 1e-6, 1e-3)
    else:
        tau = solver.tau
    two = jnp.asarray(2.0, z0.dtype)
    # z, g, H, obj, mu, nu, done, converged, stalled, (obj0, hmax, abs_obj)
    return (z0, g0, h0, obj0, tau * hmax, two, done0 | skip, done0, false, (obj0, hmax, abs_obj))


def _lm_step(pb: _Problem, solver: LevenbergMarquardt, c):
    """One Levenberg–Marquardt trial step (see `LevenbergMarquardt`); the new state."""
    z, g, h, obj, mu, nu, _, _, _, const = c
    _, hmax, abs_obj = const
    eye = np.eye(z.shape[0], dtype=z.dtype)  # a literal: no kernel builds it
    # H is symmetric: no symmetrising pass, and LAPACK's column-major operand is the
    # transpose, i.e. H as it lies (no transposing copy); NaN where not positive definite
    chol = jax.lax.linalg.cholesky((h + mu * eye).T, symmetrize_input=False)
    dz = jax.scipy.linalg.cho_solve((chol, True), -g)
    objn, gn, hn = pb.normal_equations(z + dz)
    # (few reductions: on XLA:CPU each is a kernel launch or two)
    gdz, dzdz = jnp.stack([g, dz]) @ dz  # gᵀΔz, ‖Δz‖² (non-finite iff Δz is)
    # predicted decrease −(2 gᵀΔz + ΔzᵀHΔz) with (H + μI) Δz = −g: −gᵀΔz + μ‖Δz‖²
    pred = mu * dzdz - gdz
    rho = (obj - objn) / jnp.maximum(pred, jnp.finfo(z.dtype).tiny)
    ok = (objn < obj) & jnp.isfinite(objn) & jnp.isfinite(dzdz)
    z2 = jnp.where(ok, z + dz, z)
    o2 = jnp.where(ok, objn, obj)
    g2 = jnp.where(ok, gn, g)
    h2 = jnp.where(ok, hn, h)
    mu2 = jnp.where(ok, mu * jnp.maximum(_LM_DOWN, 1.0 - (2.0 * rho - 1.0) ** 3), mu * nu)
    mu2 = jnp.maximum(mu2, 1e-15 * hmax)
    nu2 = jnp.where(ok, 2.0, nu * 2.0)
    # a vanishing step is convergence only at a stationary point: every column of J
    # (nearly) orthogonal to the residual (MINPACK's gtol test), else the solver stalled
    dg = jnp.sqrt(jnp.maximum(_diagonal(h2), 0.0) * jnp.maximum(o2, 0.0))
    # max |Δz|, and max(|g| − 1e-8 dg) ≤ 0 (stationary), in one reduction
    dz_max, g_excess = jnp.max(jnp.stack([jnp.abs(dz), jnp.abs(g2) - 1e-8 * dg]), axis=1)
    stationary = g_excess <= 0.0
    small_step = dz_max <= 1e-12
    # MINPACK's ftol test (`_ftol`): an accepted step's decrease below the tolerance, or
    # a rejected step's actual and predicted changes both below it (|F − F'| is rounding
    # noise near the minimum: float32 rejected every step there until μ blew up)
    tol = _ftol(solver, pb, obj)
    conv = (
        (o2 <= abs_obj)
        | (ok & (obj - objn <= tol))
        | ((pred <= tol) & (jnp.abs(obj - objn) <= tol))
        | (small_step & (ok | stationary))
        | (ok & (dz_max <= solver.xtol))
    )
    stuck = ~conv & (~jnp.isfinite(mu2) | (mu2 > 1e16 * hmax) | small_step)
    return (z2, g2, h2, o2, mu2, nu2, conv | stuck, conv, stuck, const)


def _lm_postprocess(pb: _Problem, solver: LevenbergMarquardt, c, steps) -> _Outcome:
    return _Outcome(c[0], steps, c[7], c[8], (c[3], c[9][0]))


# --- BFGS ------------------------------------------------------------------------------


def _line_search(pb: _Problem, gradient: str, z, f, g, d):
    """Backtracking Armijo line search (halving, at most 30 trials)."""
    gd = g @ d

    def body(c):
        alpha, _, _, _, i = c
        fn, gn = pb.value_and_grad(gradient, z + alpha * d)
        ok = jnp.isfinite(fn) & (fn <= f + 1e-4 * alpha * gd) & jnp.all(jnp.isfinite(gn))
        return jnp.where(ok, alpha, 0.5 * alpha), fn, gn, ok, i + 1

    one = jnp.asarray(1.0, z.dtype)
    c0 = (one, f, g, jnp.asarray(False), 0)
    alpha, fn, gn, ok, _ = jax.lax.while_loop(lambda c: ~c[3] & (c[4] < 30), body, c0)
    return alpha, fn, gn, ok


def _bfgs_init(pb: _Problem, solver: BFGS, skip):
    abs_obj = pb.abs_tolerance(solver.atol)
    z0 = _flat(pb.init) / pb.sv
    f0, g0 = pb.value_and_grad(solver.gradient, z0)
    c0_scale = 0.1 / jnp.maximum(jnp.max(jnp.abs(g0)), 1e-30)
    h0 = jnp.eye(z0.shape[0], dtype=z0.dtype) * c0_scale
    done0 = (f0 <= abs_obj) & ~skip
    false = jnp.asarray(False)
    # z, f, g, H, first, done, converged, stalled, (abs_obj, c0_scale)
    return (z0, f0, g0, h0, jnp.asarray(True), done0 | skip, done0, false, (abs_obj, c0_scale))


def _bfgs_step(pb: _Problem, solver: BFGS, c):
    z, f, g, h, first, _, _, _, const = c
    abs_obj, c0_scale = const
    eye = jnp.eye(z.shape[0], dtype=z.dtype)
    d = -h @ g
    descent = g @ d < 0
    d = jnp.where(descent, d, -c0_scale * g)  # not a descent direction: restart, H₀ = c₀ I
    alpha, fn, gn, ok = _line_search(pb, solver.gradient, z, f, g, d)
    s = alpha * d
    y = gn - g
    ys = y @ s
    # the matrix the update starts from: H, or c₀ I after a restart, or (yᵀs / yᵀy) I
    # after the first step (one select of the n × n matrix per step)
    rescale = first & (ys > 0)
    gamma = jnp.where(rescale, ys / jnp.maximum(y @ y, 1e-300), c0_scale)
    h = jnp.where(~descent | rescale, eye * gamma, h)
    rho = 1.0 / jnp.where(ys > 0, ys, 1.0)
    hy = h @ y  # O(n²) form of (I − ρ s yᵀ) H (I − ρ y sᵀ) + ρ s sᵀ
    hn = h + (rho * rho * (y @ hy) + rho) * jnp.outer(s, s)
    hn = hn - rho * (jnp.outer(hy, s) + jnp.outer(s, hy))
    h2 = jnp.where(ok & (ys > 1e-12 * jnp.linalg.norm(s) * jnp.linalg.norm(y)), hn, h)
    z2 = jnp.where(ok, z + s, z)
    f2 = jnp.where(ok, fn, f)
    g2 = jnp.where(ok, gn, g)
    conv = ok & ((f2 <= abs_obj) | (f - f2 <= _ftol(solver, pb, f)))
    return z2, f2, g2, h2, jnp.asarray(False), conv | ~ok, conv, ~ok, const


def _bfgs_postprocess(pb: _Problem, solver: BFGS, c, steps) -> _Outcome:
    return _Outcome(c[0], steps, c[6], c[7])


# --- Adam ------------------------------------------------------------------------------


def _adam_init(pb: _Problem, solver: Adam, skip):
    import optax

    z0 = _flat(pb.init) / pb.sv  # z = (θ, τ / L): one learning rate fits both blocks
    # z, optimiser state, converged, skip
    return z0, optax.adam(solver.learning_rate).init(z0), jnp.asarray(False), skip


def _adam_step(pb: _Problem, solver: Adam, c):
    import optax

    z, state, _, skip = c
    obj, g = pb.value_and_grad(solver.gradient, z)
    upd, state = optax.adam(solver.learning_rate).update(g, state, z)
    # converged when the objective before this update was already below the tolerance
    return optax.apply_updates(z, upd), state, obj <= pb.abs_tolerance(solver.atol), skip


def _adam_postprocess(pb: _Problem, solver: Adam, c, steps) -> _Outcome:
    return _Outcome(c[0], steps, c[2], jnp.asarray(False))


# --- optimistix ------------------------------------------------------------------------


def _optx_init(pb: _Problem, solver, skip):
    """optimistix runs its own ``iterate`` here (its solvers' init/step/terminate); the
    outer loop then has nothing left to do (``terminate`` is true at once)."""
    import optimistix as optx

    def fn(pose, args):
        return constraint_residuals(pb.model, pb.cons, pose, pb.targets, pb.init, pb.normals)

    tol = dict(rtol=solver.rtol, atol=solver.atol * pb.model.length_scale)
    cls = optx.LevenbergMarquardt if isinstance(solver, OptimistixLM) else optx.GaussNewton
    steps = jnp.where(skip, 0, solver.max_steps)
    sol = optx.least_squares(fn, cls(**tol), pb.init, max_steps=solver.max_steps, throw=False)
    ok = (sol.result == optx.RESULTS.successful) & ~skip
    z = jnp.where(skip, _flat(pb.init), _flat(sol.value)) / pb.sv
    n = jnp.minimum(jnp.asarray(sol.stats["num_steps"], jnp.int32), steps)
    return z, n, ok


def _optx_postprocess(pb: _Problem, solver, c, steps) -> _Outcome:
    return _Outcome(c[0], c[1], c[2], jnp.asarray(False))
