"""Mesh-IK solvers as small frozen objects (after optimistix's ``LevenbergMarquardt(rtol,
atol)``): Levenberg–Marquardt on the analytic Jacobian, BFGS on the factored gradient
(eq. (13)), optax Adam, optimistix least squares (Park, Kang & Kwon, §4).

`solve_ik` minimises ``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` (eq. (1)) plus the constraint blocks
of `fxspace.mesh.IKConstraints` for one frame; `track_ik` does it frame by frame along
an animation (``lax.scan``, warm-started). The solver is an object, passed as
``solver=``; it is hashable (static under ``jit``):

* `LevenbergMarquardt` (the default): the normal equations from the analytic Jacobian
  (those of `fxspace.ik_normal_equations`, built in few kernels by
  `fxspace.mesh._ik_gradients.gram_normal_equations`), Levenberg damping in scaled
  coordinates, Nielsen's damping update (floor 1/5), Cholesky solves.
* `BFGS`: quasi-Newton (dense inverse-Hessian update, backtracking Armijo line search),
  driven only by ``(E, ∇E)`` — the paper's setting, where the gradient is the cost: the
  gradient form is selectable (``"factored"``, eq. (13); ``"naive"``, eq. (9);
  ``"autodiff"``), so the solver measures what eq. (13) buys per solved frame.
* `Adam`: first-order, optax Adam on the chosen gradient.
* `OptimistixLM` / `OptimistixGaussNewton`: optimistix's solvers on the residual vector
  (Jacobian by autodiff).

Every solver supplies ``init / step / terminate / postprocess``; one loop, `_iterate`,
drives them all (optimistix's pattern). A method *name* from a config
(``"lm"``, ``"bfgs"``, ``"adam"``, ``"optx_lm"``, ``"optx_gn"``) becomes an object
through `solver_from_method`; `solve_ik` itself takes only objects.

Example:

```python
res = fx.solve_ik(model, targets)                                  # LM from rest
res = fx.solve_ik(model, targets, solver=fx.mesh.BFGS(gradient="naive", rtol=1e-3))
tr = fx.track_ik(model, frames, solver=fx.mesh.LevenbergMarquardt(rtol=1e-3))
```
"""

from __future__ import annotations

import dataclasses
import functools
from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import check_choice, check_int, check_scalar
from fxspace.errors import FxspaceError
from fxspace.mesh._ik_constraints import (
    IKConstraints,
    constrained_normal_equations,
    constrained_value_and_gradient,
    constraint_residuals,
)
from fxspace.mesh._ik_gradients import GRADIENTS
from fxspace.mesh._ik_model import IKModel, IKResult, ik_residuals
from fxspace.mesh._ik_regularizers import IKRegularization
from fxspace.mesh._skinning import Pose
from fxspace.results import check_result, result_from_flags

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "Method",
    "LevenbergMarquardt",
    "BFGS",
    "Adam",
    "OptimistixLM",
    "OptimistixGaussNewton",
    "Solver",
    "solver_from_method",
    "solve_ik",
    "track_ik",
]

Method = Literal["lm", "bfgs", "optx_lm", "optx_gn", "adam"]
METHODS: tuple[str, ...] = ("lm", "bfgs", "optx_lm", "optx_gn", "adam")
DEFAULT_METHOD: Method = "lm"
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
_SOLVERS = (LevenbergMarquardt, BFGS, Adam, OptimistixLM, OptimistixGaussNewton)
_BY_METHOD = {
    "lm": LevenbergMarquardt,
    "bfgs": BFGS,
    "adam": Adam,
    "optx_lm": OptimistixLM,
    "optx_gn": OptimistixGaussNewton,
}


def solver_from_method(
    method: str = DEFAULT_METHOD,
    *,
    gradient: str | None = None,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    learning_rate: float | None = None,
) -> Solver:
    """The solver object of the old string form (``method="lm"`` …); unset keywords keep
    the object's defaults, keywords a solver has no use for are ignored as before."""
    check_choice(method, "method", METHODS)
    cls = _BY_METHOD[method]
    given = dict(
        gradient=gradient,
        max_steps=max_steps,
        rtol=rtol,
        atol=atol,
        learning_rate=learning_rate,
    )
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in given.items() if v is not None and k in names})


def _flat(pose: Pose) -> Array:
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


def _unflat(x: Array, nj: int) -> Pose:
    return Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :])


class _Problem:
    """The data of one frame's solve, bundled for the solver loops (not a pytree: built
    inside the jitted function, never crosses a ``jit`` boundary)."""

    def __init__(self, model, cons, targets, init, normals):
        self.model, self.cons, self.targets = model, cons, targets
        self.init, self.normals = init, normals
        self.nj = model.ancestors.shape[0]
        self.target_norm = jnp.sqrt(jnp.sum(targets * targets))
        scale = model.length_scale
        self.sv = jnp.concatenate(
            [jnp.ones(3 * self.nj, targets.dtype), jnp.full(3, scale, targets.dtype)]
        )

    def abs_tolerance(self, atol: float) -> Array:
        return (atol * self.model.length_scale) ** 2 * self.targets.shape[0]

    def pose(self, z: Array) -> Pose:
        return _unflat(z * self.sv, self.nj)

    def value_and_grad(self, gradient: str, z: Array) -> tuple[Array, Array]:
        v, g = constrained_value_and_gradient(
            gradient, self.model, self.cons, self.pose(z), self.targets, self.init, self.normals
        )
        return v, _flat(g) * self.sv

    def normal_equations(self, z: Array) -> tuple[Array, Array, Array]:
        obj, g, h = constrained_normal_equations(
            self.model, self.cons, self.pose(z), self.targets, self.init, self.normals
        )
        sv = self.sv
        return obj, g * sv, h * (sv[:, None] * sv[None, :])


def _ftol(solver, pb: _Problem, obj: Array) -> Array:
    """The decrease of ``F`` below which a step counts as none: ``rtol · F``, floored at
    what rounding lets the dtype resolve. A residual ``r = p − t`` of positions of size
    ``|t|`` carries an error ``ε|t|`` (cancellation), so ``F = Σ r²`` is known to about
    ``2 ε Σ |r||t| ≤ 2 ε √F ‖t‖``. In float32 near a minimum that is far above
    ``1e-6 · F``: the steps there were rejected as rounding noise until the damping blew
    up (CesiumMan, 120 markers, from rest: 26 LM iterations and ``stalled`` in float32
    against 13.7 and ``successful`` in float64); in float64 the floor never binds."""
    eps = float(jnp.finfo(obj.dtype).eps)
    return jnp.maximum(solver.rtol * obj, 2.0 * eps * pb.target_norm * jnp.sqrt(obj))


def _diagonal(h: Array) -> Array:
    """``diag(h)`` as a strided slice (``jnp.diagonal`` is a gather with an index table)."""
    return h.reshape(-1)[:: h.shape[0] + 1]


class _Outcome(NamedTuple):
    """What `postprocess` hands back: the pose in scaled coordinates, the step count,
    the flags, and the objective at the end and at the start where the solver knows it
    without another forward pass (``None`` otherwise)."""

    z: Array
    steps: Array
    converged: Array
    stalled: Array
    objective: tuple[Array, Array] | None = None


def _iterate(pb: _Problem, solver: Solver, skip) -> _Outcome:
    """The one loop of every IK solver (after optimistix's ``iterate``): ``state =
    solver.init(pb, skip)``, then ``solver.step`` while fewer than ``max_steps`` steps
    were taken and ``solver.terminate(state)`` is false, then ``solver.postprocess``.
    ``skip`` (non-finite input) starts the loop finished: no ``lax.cond`` (XLA:CPU runs a
    conditional's branch as a task on its thread pool, a thread hop per call)."""
    state = solver.init(pb, jnp.asarray(skip, bool))

    def cond(c):
        k, s = c
        return (k < solver.max_steps) & ~solver.terminate(s)

    def body(c):
        k, s = c
        return k + 1, solver.step(pb, s)

    k, state = jax.lax.while_loop(cond, body, (jnp.asarray(0, jnp.int32), state))
    return solver.postprocess(pb, state, k)


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


def _result(model, cons, pose, targets, init, normals, steps, result, solver) -> IKResult:
    d = ik_residuals(model, pose, targets)
    sq = jnp.sum(d * d, axis=-1)
    if all(block is None for block in cons):  # no constraint: E, from the same pass
        obj = jnp.sum(sq)
    else:
        obj = jnp.sum(constraint_residuals(model, cons, pose, targets, init, normals) ** 2)
    if cons.marker_weights is not None:
        on = cons.marker_weights > 0
        rms = jnp.sqrt(jnp.sum(jnp.where(on, sq, 0.0)) / jnp.maximum(jnp.sum(on), 1))
    else:
        rms = jnp.sqrt(jnp.sum(sq) / sq.shape[0])
    stats = {"max_steps": jnp.asarray(solver.max_steps, jnp.int32), "objective": obj}
    return IKResult(pose, rms, obj, jnp.asarray(steps, jnp.int32), result, stats)


@partial(jax.jit, static_argnames=("solver",))
def _solve(model, cons, targets, init, normals, solver):
    """One frame; non-finite inputs skip the solve (``nonfinite_input``, the initial pose
    returned), a non-finite final iterate is replaced by the initial pose
    (``nonfinite_output``)."""
    finite_in = jnp.all(jnp.isfinite(targets)) & jnp.all(jnp.isfinite(_flat(init)))
    if normals is not None:
        finite_in = finite_in & jnp.all(jnp.isfinite(normals))
    safe_t = jnp.where(finite_in, targets, 0.0)
    safe_n = None if normals is None else jnp.where(finite_in, normals, 0.0)
    safe_init = jax.tree_util.tree_map(lambda a: jnp.where(finite_in, a, 0.0), init)
    pb = _Problem(model, cons, safe_t, safe_init, safe_n)
    out = _iterate(pb, solver, ~finite_in)
    pose = jax.tree_util.tree_map(lambda a, b: jnp.where(finite_in, a, b), pb.pose(out.z), init)
    finite_out = jnp.all(jnp.isfinite(_flat(pose)))
    pose = jax.tree_util.tree_map(lambda a, b: jnp.where(finite_out, a, b), pose, init)
    result = result_from_flags(
        converged=out.converged,
        nonfinite_input=~finite_in,
        nonfinite_output=finite_in & ~finite_out,
        stalled=out.stalled,
    )
    steps = jnp.asarray(out.steps, jnp.int32)
    if out.objective is not None and all(block is None for block in cons):
        # E at the returned pose is the solver's own (no forward pass again): at the last
        # iterate, or at the start when that pose is replaced; NaN for non-finite input
        obj_end, obj0 = out.objective
        obj = jnp.where(finite_in, jnp.where(finite_out, obj_end, obj0), jnp.nan)
        rms = jnp.sqrt(obj / targets.shape[0])
        stats = {"max_steps": jnp.asarray(solver.max_steps, jnp.int32), "objective": obj}
        return IKResult(pose, rms, obj, steps, result, stats)
    return _result(model, cons, pose, targets, init, normals, steps, result, solver)


@partial(jax.jit, static_argnames=("solver",))
def _track(model, cons, targets, init, normals, solver):
    def step(pose, xs):
        tgt, nrm = xs
        res = _solve(model, cons, tgt, pose, nrm, solver)
        return res.pose, res

    _, out = jax.lax.scan(step, init, (targets, normals))
    return out


def _pick_solver(solver) -> Solver:
    if solver is None:
        return LevenbergMarquardt()
    if not isinstance(solver, _SOLVERS):
        raise FxspaceError(
            "solver must be fx.mesh.LevenbergMarquardt(...), BFGS(...), Adam(...), "
            f"OptimistixLM(...) or OptimistixGaussNewton(...); got {solver!r} "
            "(a method name from a config: fx.mesh.solver_from_method(name, ...))"
        )
    return solver


def _pick_constraints(constraints) -> IKConstraints:
    if constraints is None:
        return IKConstraints()
    if isinstance(constraints, IKRegularization):
        raise FxspaceError(
            "constraints must be an IKConstraints; turn an ik_regularization(...) into one "
            "with fx.mesh.constraints_from_regularization(reg)"
        )
    if not isinstance(constraints, IKConstraints):
        raise FxspaceError("constraints must come from fxspace.mesh.ik_constraints(...)")
    return constraints


@functools.lru_cache(maxsize=64)
def _rest_init(nj: int, dtype) -> Pose:
    """The rest pose (zeros) as device arrays, made once per size and dtype: a per-frame
    call then pays no allocation for its default start (arrays are immutable)."""
    with jax.ensure_compile_time_eval():  # concrete even when first called under jit
        return Pose(jnp.zeros((nj, 3), dtype), jnp.zeros((3,), dtype))


def _prepare(model, targets, init, solver, constraints, normals, frames: bool):
    """Checked arguments of `_solve` / `_track` (shared by the public entry points)."""
    if not isinstance(model, IKModel):
        raise FxspaceError("model must be an IKModel from fxspace.ik_model(mesh, markers)")
    solver = _pick_solver(solver)
    cons = _pick_constraints(constraints)
    if not isinstance(targets, jax.Array):  # (jnp.asarray costs ~15 µs even on an Array)
        targets = jnp.asarray(targets)
    nk = model.marker_joints.shape[0]
    want = "(frames, markers, 3)" if frames else "(markers, 3)"
    if targets.ndim != (3 if frames else 2) or targets.shape[-2:] != (nk, 3):
        raise FxspaceError(
            f"targets must have shape {want} for this model's {nk} markers, got {targets.shape}"
        )
    if not jnp.issubdtype(targets.dtype, jnp.floating) or targets.dtype == jnp.float16:
        raise FxspaceError(f"targets must be float32 or float64, got dtype {targets.dtype}")
    # the precision of the solve: the model's where it is wider (float32 targets against a
    # float64 model, JAX's default dtype under jax_enable_x64, solve in float64: the
    # loop's carry keeps one dtype, and float32 stopping tests take more iterations)
    dtype = jnp.promote_types(model.marker_skin.dtype, targets.dtype)
    if targets.dtype != dtype:
        targets = targets.astype(dtype)
    nj = model.ancestors.shape[0]
    if init is None:
        init = _rest_init(nj, jnp.dtype(dtype))
    elif (
        not isinstance(init, Pose) or init.angles.shape != (nj, 3) or init.translation.shape != (3,)
    ):
        raise FxspaceError(f"init must be a Pose with angles ({nj}, 3) and translation (3,)")
    elif init.angles.dtype != dtype or init.translation.dtype != dtype:
        init = Pose(jnp.asarray(init.angles, dtype), jnp.asarray(init.translation, dtype))
    if cons.normal is not None:
        if normals is None:
            raise FxspaceError("the normal constraint needs target_normals (one row per marker)")
        normals = jnp.asarray(normals, targets.dtype)
        kn = cons.normal.corners.marker_joints.shape[0] // 3
        lead = targets.shape[:1] if frames else ()
        if normals.shape != lead + (kn, 3):
            raise FxspaceError(
                f"target_normals must have shape {lead + (kn, 3)}, got {normals.shape}"
            )
        if not isinstance(normals, jax.core.Tracer):
            nrm = np.linalg.norm(np.asarray(normals), axis=-1)
            if not np.all(nrm > 1e-6):
                bad = np.argwhere(~(nrm > 1e-6))[0].tolist()
                raise FxspaceError(
                    f"target_normals must be non-zero, finite unit vectors; row {bad} has "
                    f"length {nrm[tuple(bad)]:g}"
                )
    elif normals is not None:
        raise FxspaceError("target_normals given without a normal constraint; add one first")
    return model, cons, targets, init, normals, solver


def solve_ik(
    model: IKModel,
    targets: Float[Array, "markers 3"],
    init: Pose | None = None,
    *,
    solver: Solver | None = None,
    constraints: IKConstraints | None = None,
    target_normals: Float[Array, "normals 3"] | None = None,
    throw: bool = False,
) -> IKResult:
    """Pose that brings the markers to ``targets``: ``argmin_θ E(θ)`` (eq. (1)) plus the
    constraints, one frame.

    **Arguments:**

    - `model`: from `fxspace.ik_model`.
    - `targets`: ``(K, 3)`` marker targets.
    - `init`: starting pose (default: the rest pose, a cold start as in the paper); pass
      the previous frame's pose to warm-start along an animation (`track_ik`).
    - `solver`: a solver object, `LevenbergMarquardt` (default), `BFGS`, `Adam`,
      `OptimistixLM`, `OptimistixGaussNewton`.
    - `constraints`: an `IKConstraints` (`fxspace.mesh.ik_constraints`): marker weights,
      surface normals at markers, plane contacts, joint limits, joint prior; every
      solver takes every block.
    - `target_normals`: ``(K_n, 3)`` unit target normals when a normal constraint is on.
    - `throw`: raise `FxspaceError` when the result is not ``RESULTS.successful``.

    **Returns:** `fxspace.IKResult` (pose, RMS residual, objective, ``num_steps``,
    ``result``, ``stats``; ``converged`` and ``status`` for old callers). Targets or an
    initial pose with NaN/inf give ``result == RESULTS.nonfinite_input`` and the initial
    pose. Jitted (the solver is static); vmappable over targets.

    Example: ``res = fx.solve_ik(model, targets); res.pose, bool(res.converged)``.
    """
    args = _prepare(model, targets, init, solver, constraints, target_normals, False)
    res = _solve(*args)
    return check_result(res.result, throw, "solve_ik", res)


def track_ik(
    model: IKModel,
    targets: Float[Array, "frames markers 3"],
    init: Pose | None = None,
    *,
    solver: Solver | None = None,
    constraints: IKConstraints | None = None,
    target_normals: Float[Array, "frames normals 3"] | None = None,
    throw: bool = False,
) -> IKResult:
    """`solve_ik` frame by frame along ``targets``, each frame warm-started from the last.

    One ``lax.scan``; returns an `fxspace.IKResult` whose fields have a leading frame
    axis. Keywords as `solve_ik` (``target_normals`` then has a leading frame axis too).
    A frame with NaN targets keeps the previous pose (``RESULTS.nonfinite_input``) and
    the next frame starts from there; ``throw=True`` raises naming the first such frame.
    """
    args = _prepare(model, targets, init, solver, constraints, target_normals, True)
    res = _track(*args)
    return check_result(res.result, throw, "track_ik", res)
