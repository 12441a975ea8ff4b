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

The old string form ``method="lm"`` (``"bfgs"``, ``"adam"``, ``"optx_lm"``,
``"optx_gn"``) with ``gradient=``, ``max_steps=``, ``rtol=``, ``atol=``,
``learning_rate=`` keeps working: `solver_from_method` maps it onto the objects.

Example:

```python
res = fx.solve_ik(model, targets)                                  # LM from rest
res = fx.solve_ik(model, targets, solver=fx.mesh.BFGS(gradient="naive", rtol=1e-3))
tr = fx.track_ik(model, frames, solver=fx.mesh.LevenbergMarquardt(rtol=1e-3))
```
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Literal

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
from fxspace.mesh._ik_regularizers import IKRegularization, constraints_from_regularization
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


@dataclasses.dataclass(frozen=True)
class OptimistixLM:
    """optimistix's Levenberg–Marquardt on the residual vector (autodiff Jacobian)."""

    rtol: float = 1e-6
    atol: float = 1e-7
    max_steps: int = 50

    def __post_init__(self):
        _check_common(self)


@dataclasses.dataclass(frozen=True)
class OptimistixGaussNewton:
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


def _diagonal(h: Array) -> Array:
    """``diag(h)`` as a strided slice (``jnp.diagonal`` is a gather with an index table)."""
    return h.reshape(-1)[:: h.shape[0] + 1]


def _lm_step(pb: _Problem, solver: LevenbergMarquardt, abs_obj, hmax, c):
    """One Levenberg–Marquardt trial step (see `_solve_lm`); returns the new carry."""
    z, g, h, obj, mu, nu, step, _, _, _ = c
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
    conv = (
        (o2 <= abs_obj)
        | (ok & (obj - objn <= solver.rtol * obj))
        | (small_step & (ok | stationary))
        | (ok & (dz_max <= solver.xtol))
    )
    stuck = ~conv & (~jnp.isfinite(mu2) | (mu2 > 1e16 * hmax) | small_step)
    return (z2, g2, h2, o2, mu2, nu2, step + 1, conv | stuck, conv, stuck)


def _solve_lm(pb: _Problem, solver: LevenbergMarquardt, skip=False):
    """Levenberg–Marquardt in scaled coordinates ``z = (θ, τ / L)``, Levenberg damping
    ``(JᵀJ + μ I) Δz = −Jᵀr`` with ``μ₀ = τ · max diag(JᵀJ)`` and Nielsen's update of
    ``μ`` with the floor 1/5 (``μ ← μ · max(1/5, 1 − (2ρ − 1)³)`` on success; Nielsen's
    own floor is 1/3), Cholesky solves; ``skip``: take no step (non-finite input). Returns
    the pose, steps, converged, stalled and the objective at the end and at the start.

    Why ``μ I`` and not Marquardt's ``μ diag(JᵀJ)``: measured on CesiumMan, Fox and
    RiggedSimple (5–120 markers, cold starts), the diagonal scaling stalls in long valleys
    (CesiumMan 120 markers: 21 vs 13 iterations to the same vertex error; Fox 50 markers:
    vertex error 0.34 vs 3e-6) — the scaled coordinates make one ``μ`` fit angles and the
    translation alike. Why the floor 1/5: from rest the steps are accepted with ``ρ ≈ 1``
    and the damping, not the model, limits them (``μ`` falls by the floor at every step).
    Measured on the same meshes (5–120 markers from two random views, cold and warm, 30
    frames each): 13.1 iterations on average against 14.6 with 1/3 at the same vertex
    errors; CesiumMan, 120 markers, from rest: 11.2 against 13.0. The floor 1/10 takes
    fewer still (12.2; 10.1) but its rtol-1e-3 stops land further above the minimum on a
    noisy CesiumMan frame (1.2 % vs 0.3 %, `tests/mesh/test_ik_solvers.py`). Every trial
    point costs one evaluation of the normal equations (accepted steps reuse it).
    """
    abs_obj = pb.abs_tolerance(solver.atol)
    skip = jnp.asarray(skip, bool)
    z0 = _flat(pb.init) / pb.sv
    obj0, g0, h0 = pb.normal_equations(z0)
    hmax = jnp.maximum(jnp.max(_diagonal(h0)), jnp.finfo(z0.dtype).tiny)
    done0 = (obj0 <= abs_obj) & ~skip
    false = jnp.asarray(False)
    # carry: z, g, H, obj, mu, nu, step, done, converged, stalled
    if solver.tau is None:  # warm start (RMS residual < 1 % of L): Gauss–Newton at once
        near = obj0 < (0.01 * pb.model.length_scale) ** 2 * pb.targets.shape[0]
        tau = jnp.where(near, 1e-6, 1e-3)
    else:
        tau = solver.tau
    c0 = (z0, g0, h0, obj0, tau * hmax, jnp.asarray(2.0, z0.dtype), 0, done0 | skip, done0, false)
    out = jax.lax.while_loop(
        lambda c: (c[6] < solver.max_steps) & ~c[7],
        partial(_lm_step, pb, solver, abs_obj, hmax),
        c0,
    )
    # the objective at the end and at the start (the result's, without a forward pass)
    return pb.pose(out[0]), out[6], out[8], out[9], (out[3], obj0)


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


def _bfgs_step(pb: _Problem, solver: BFGS, abs_obj, c0_scale, c):
    z, f, g, h, step, _, _, _ = c
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
    rescale = (step == 0) & (ys > 0)
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
    conv = ok & ((f2 <= abs_obj) | (f - f2 <= solver.rtol * f))
    return z2, f2, g2, h2, step + 1, conv | ~ok, conv, ~ok


def _solve_bfgs(pb: _Problem, solver: BFGS):
    """BFGS in scaled coordinates ``z = (θ, τ / L)``, backtracking Armijo line search.

    Each trial point costs one forward pass + one gradient of the chosen form (value and
    gradient together); the inverse Hessian ``H`` starts as ``0.1 / ‖∇E‖_∞ · I`` (first
    step: at most 0.1 rad), is rescaled by ``yᵀs / yᵀy`` after the first step and updated
    by ``H ← (I − ρ s yᵀ) H (I − ρ y sᵀ) + ρ s sᵀ`` (in its ``O(n²)`` form) when ``yᵀs > 0``.
    """
    abs_obj = pb.abs_tolerance(solver.atol)
    z0 = _flat(pb.init) / pb.sv
    f0, g0 = pb.value_and_grad(solver.gradient, z0)
    c0_scale = 0.1 / jnp.maximum(jnp.max(jnp.abs(g0)), 1e-30)
    h0 = jnp.eye(z0.shape[0], dtype=z0.dtype) * c0_scale
    done0 = f0 <= abs_obj
    false = jnp.asarray(False)
    # carry: z, f, g, H, step, done, converged, stalled
    out = jax.lax.while_loop(
        lambda c: (c[4] < solver.max_steps) & ~c[5],
        partial(_bfgs_step, pb, solver, abs_obj, c0_scale),
        (z0, f0, g0, h0, 0, done0, done0, false),
    )
    return pb.pose(out[0]), out[4], out[6], out[7]


def _solve_optx(pb: _Problem, solver):
    import optimistix as optx

    def fn(pose, args):
        return constraint_residuals(pb.model, pb.cons, pose, pb.targets, pb.init, pb.normals)

    tol = dict(rtol=solver.rtol, atol=solver.atol * pb.model.length_scale)
    cls = optx.LevenbergMarquardt if isinstance(solver, OptimistixLM) else optx.GaussNewton
    sol = optx.least_squares(fn, cls(**tol), pb.init, max_steps=solver.max_steps, throw=False)
    ok = sol.result == optx.RESULTS.successful
    return sol.value, sol.stats["num_steps"], ok, jnp.asarray(False)


def _solve_adam(pb: _Problem, solver: Adam):
    import optax

    abs_obj = pb.abs_tolerance(solver.atol)
    opt = optax.adam(solver.learning_rate)
    # optimise z = (θ, τ / L), so one learning rate fits both blocks
    z0 = _flat(pb.init) / pb.sv

    def body(c):
        z, state, step, _ = c
        obj, g = pb.value_and_grad(solver.gradient, z)
        upd, state = opt.update(g, state, z)
        # converged when the objective before this update was already below the tolerance
        return optax.apply_updates(z, upd), state, step + 1, obj <= abs_obj

    c0 = (z0, opt.init(z0), 0, jnp.asarray(False))
    z, _, steps, conv = jax.lax.while_loop(lambda c: (c[2] < solver.max_steps) & ~c[3], body, c0)
    return pb.pose(z), steps, conv, jnp.asarray(False)


def _dispatch(pb: _Problem, solver: Solver):
    if isinstance(solver, LevenbergMarquardt):
        return _solve_lm(pb, solver)
    if isinstance(solver, BFGS):
        return _solve_bfgs(pb, solver)
    if isinstance(solver, Adam):
        return _solve_adam(pb, solver)
    return _solve_optx(pb, solver)


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

    def run():
        pb = _Problem(model, cons, safe_t, init, safe_n)
        pose, steps, conv, stalled = _dispatch(pb, solver)
        return pose, jnp.asarray(steps, jnp.int32), jnp.asarray(conv), jnp.asarray(stalled)

    def skip():
        f = jnp.asarray(False)
        return init, jnp.asarray(0, jnp.int32), f, f

    if isinstance(solver, LevenbergMarquardt):
        # no lax.cond: XLA:CPU runs a conditional's branch as a task on its thread pool, a
        # thread hop per call; the loop starts finished instead (no step on bad input)
        safe_init = jax.tree_util.tree_map(lambda a: jnp.where(finite_in, a, 0.0), init)
        pb = _Problem(model, cons, safe_t, safe_init, safe_n)
        pose, steps, conv, stalled, (obj_end, obj0) = _solve_lm(pb, solver, skip=~finite_in)
        pose = jax.tree_util.tree_map(lambda a, b: jnp.where(finite_in, a, b), pose, init)
        steps = jnp.asarray(steps, jnp.int32)
    else:
        pose, steps, conv, stalled = jax.lax.cond(finite_in, run, skip)
    finite_out = jnp.all(jnp.isfinite(_flat(pose)))
    pose = jax.tree_util.tree_map(lambda a, b: jnp.where(finite_out, a, b), pose, init)
    result = result_from_flags(
        converged=conv,
        nonfinite_input=~finite_in,
        nonfinite_output=finite_in & ~finite_out,
        stalled=stalled,
    )
    if isinstance(solver, LevenbergMarquardt) and all(block is None for block in cons):
        # E at the returned pose is the solver's own (no forward pass again): at the last
        # iterate, or at the start when that pose is replaced; NaN for non-finite input
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


_LEGACY = ("method", "gradient", "max_steps", "rtol", "atol", "learning_rate")


def _pick_solver(solver, legacy: dict) -> Solver:
    given = {k: v for k, v in legacy.items() if v is not None and k in _LEGACY}
    if solver is not None:
        if given:
            raise FxspaceError(
                f"pass either solver= or the old keywords {sorted(given)}, not both "
                "(e.g. solver=fx.mesh.BFGS(rtol=1e-3))"
            )
        if not isinstance(solver, _SOLVERS):
            raise FxspaceError(
                "solver must be fx.mesh.LevenbergMarquardt(...), BFGS(...), Adam(...), "
                f"OptimistixLM(...) or OptimistixGaussNewton(...); got {solver!r}"
            )
        return solver
    method = given.pop("method", DEFAULT_METHOD)
    if method not in METHODS:
        raise FxspaceError(f"method must be one of {METHODS}, got {method!r}")
    if "gradient" in given and given["gradient"] not in GRADIENTS:
        raise FxspaceError(f"gradient must be one of {GRADIENTS}, got {given['gradient']!r}")
    return solver_from_method(method, **given)


def _pick_constraints(model: IKModel, constraints, regularization) -> IKConstraints:
    if regularization is not None:
        if constraints is not None:
            raise FxspaceError("pass either constraints= or regularization=, not both")
        if not isinstance(regularization, IKRegularization):
            raise FxspaceError("regularization must come from fxspace.mesh.ik_regularization(...)")
        return constraints_from_regularization(regularization)
    if constraints is None:
        return IKConstraints()
    if not isinstance(constraints, IKConstraints):
        raise FxspaceError("constraints must come from fxspace.mesh.ik_constraints(...)")
    return constraints


def _prepare(model, targets, init, solver, constraints, normals, legacy, frames: bool):
    """Checked arguments of `_solve` / `_track` (shared by the public entry points)."""
    if not isinstance(model, IKModel):
        raise FxspaceError("model must be an IKModel from fxspace.ik_model(mesh, markers)")
    solver = _pick_solver(solver, legacy)
    cons = _pick_constraints(model, constraints, legacy.get("regularization"))
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
    nj = model.ancestors.shape[0]
    if init is None:
        init = Pose(jnp.zeros((nj, 3), targets.dtype), jnp.zeros((3,), targets.dtype))
    elif (
        not isinstance(init, Pose) or init.angles.shape != (nj, 3) or init.translation.shape != (3,)
    ):
        raise FxspaceError(f"init must be a Pose with angles ({nj}, 3) and translation (3,)")
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
    method: Method | None = None,
    gradient: str | None = None,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    learning_rate: float | None = None,
    regularization: IKRegularization | None = None,
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
    - `method`, `gradient`, `max_steps`, `rtol`, `atol`, `learning_rate`: the old string
      form of `solver` (see `solver_from_method`); `regularization`: the old form of
      `constraints` (`fxspace.mesh.ik_regularization`).

    **Returns:** `fxspace.IKResult` (pose, RMS residual, objective, ``num_steps``,
    ``result``, ``stats``; ``converged`` and ``status`` for old callers). Targets or an
    initial pose with NaN/inf give ``result == RESULTS.nonfinite_input`` and the initial
    pose. Jitted (the solver is static); vmappable over targets.

    Example: ``res = fx.solve_ik(model, targets); res.pose, bool(res.converged)``.
    """
    legacy = dict(
        zip(_LEGACY, (method, gradient, max_steps, rtol, atol, learning_rate), strict=True)
    )
    legacy["regularization"] = regularization
    args = _prepare(model, targets, init, solver, constraints, target_normals, legacy, False)
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
    method: Method | None = None,
    gradient: str | None = None,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    learning_rate: float | None = None,
    regularization: IKRegularization | None = None,
) -> IKResult:
    """`solve_ik` frame by frame along ``targets``, each frame warm-started from the last.

    One ``lax.scan``; returns an `fxspace.IKResult` whose fields have a leading frame
    axis. Keywords as `solve_ik` (``target_normals`` then has a leading frame axis too).
    A frame with NaN targets keeps the previous pose (``RESULTS.nonfinite_input``) and
    the next frame starts from there; ``throw=True`` raises naming the first such frame.
    """
    legacy = dict(
        zip(_LEGACY, (method, gradient, max_steps, rtol, atol, learning_rate), strict=True)
    )
    legacy["regularization"] = regularization
    args = _prepare(model, targets, init, solver, constraints, target_normals, legacy, True)
    res = _track(*args)
    return check_result(res.result, throw, "track_ik", res)
