"""Mesh-IK solvers: BFGS on the factored gradient (eq. (13)), Levenberg–Marquardt on the
analytic Jacobian, optimistix least squares and optax Adam (Park, Kang & Kwon, §4).

:func:`solve_ik` minimises ``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` (eq. (1)), plus the optional
regularisers of :mod:`fxspace.mesh._ik_regularizers`, for one frame;
:func:`track_ik` does it frame by frame along an animation (``lax.scan``, warm-started).

* ``"bfgs"``: quasi-Newton (BFGS, dense inverse-Hessian update, backtracking Armijo
  line search) in a ``lax.while_loop``, driven only by ``(E, ∇E)`` — the paper's setting,
  where the gradient is the cost: the gradient form is selectable (``"factored"``,
  eq. (13); ``"naive"``, eq. (9); ``"autodiff"``), so the solver measures what eq. (13)
  buys per solved frame. Angles and the translation (in units of the mesh's size) are
  one vector.
* ``"lm"``: Levenberg–Marquardt on the normal equations built from the analytic Jacobian
  (:func:`fxspace.ik_normal_equations`), Levenberg damping in scaled coordinates,
  Nielsen's damping update, Cholesky solves.
* ``"optx_lm"`` / ``"optx_gn"``: optimistix's Levenberg–Marquardt / Gauss–Newton
  (Jacobian by autodiff).
* ``"adam"``: first-order, optax Adam on the chosen gradient.

Example:

```python
res = fx.solve_ik(model, targets)                 # cold start from the rest pose
res = fx.solve_ik(model, targets, method="bfgs", gradient="naive")
tr = fx.track_ik(model, targets_per_frame)        # warm-started along the frames
```
"""

from __future__ import annotations

from functools import partial
from typing import Literal

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace.errors import FxspaceError
from fxspace.mesh._ik_gradients import (
    GRADIENTS,
    Gradient,
    ik_normal_equations,
    value_and_gradient,
)
from fxspace.mesh._ik_model import IKModel, IKResult, ik_residuals
from fxspace.mesh._ik_regularizers import IKRegularization, regularization_value_and_gradient
from fxspace.mesh._skinning import Pose

__all__ = ["METHODS", "DEFAULT_METHOD", "Method", "solve_ik", "track_ik"]

Method = Literal["lm", "bfgs", "optx_lm", "optx_gn", "adam"]
METHODS: tuple[str, ...] = ("lm", "bfgs", "optx_lm", "optx_gn", "adam")
DEFAULT_METHOD: Method = "lm"
_DEFAULT_STEPS = {"lm": 50, "bfgs": 200, "optx_lm": 50, "optx_gn": 50, "adam": 50}
_CONVERGED, _MAX_STEPS, _NON_FINITE, _STALLED = 0, 1, 2, 3
_LM_TAU = 1e-3  # μ₀ = τ · max diag(JᵀJ)
_LM_DOWN = 1.0 / 3.0


def _flat(pose: Pose) -> Array:
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


def _unflat(x: Array, nj: int) -> Pose:
    return Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :])


def _total(gradient, model, pose, targets, reg, init, normals):
    """(E + R, ∇(E + R)) with the chosen gradient form for E."""
    val, g = value_and_gradient(gradient, model, pose, targets)
    if reg is None:
        return val, g
    rv, rg, _ = regularization_value_and_gradient(reg, model.length_scale, pose, init, normals)
    return val + rv, jax.tree_util.tree_map(jnp.add, g, rg)


def _result(model, pose, targets, steps, status, reg, init, normals) -> IKResult:
    d = ik_residuals(model, pose, targets)
    obj = jnp.sum(d * d)
    if reg is not None:
        obj = (
            obj + regularization_value_and_gradient(reg, model.length_scale, pose, init, normals)[0]
        )
    rms = jnp.sqrt(jnp.sum(d * d) / d.shape[0])
    status = jnp.asarray(status, jnp.int32)
    return IKResult(pose, rms, obj, jnp.asarray(steps, jnp.int32), status == _CONVERGED, status)


def _solve_lm(model, targets, init, max_steps, rtol, atol, reg, normals):
    """Levenberg–Marquardt with the analytic Jacobian, in scaled coordinates
    ``z = (θ, τ / L)``, Levenberg damping ``(JᵀJ + μ I) Δz = −Jᵀr`` with
    ``μ₀ = 10⁻³ · max diag(JᵀJ)`` and Nielsen's update of ``μ``, Cholesky solves.

    Why ``μ I`` and not Marquardt's ``μ diag(JᵀJ)``: measured on CesiumMan, Fox and
    RiggedSimple (5–120 markers, cold starts), the diagonal scaling stalls in long valleys
    (CesiumMan 120 markers: 21 vs 13 iterations to the same vertex error; Fox 50 markers:
    vertex error 0.34 vs 3e-6) — the scaled coordinates make one ``μ`` fit angles and the
    translation alike. Every trial point costs one evaluation of the normal equations
    (accepted steps reuse it).
    """
    nj = model.ancestors.shape[0]
    nk = targets.shape[0]
    abs_obj = (atol * model.length_scale) ** 2 * nk
    sv = jnp.concatenate(
        [jnp.ones(3 * nj, targets.dtype), jnp.full(3, model.length_scale, targets.dtype)]
    )

    def lin(z):
        pose = _unflat(z * sv, nj)
        r, g, h = ik_normal_equations(model, pose, targets)
        obj = r.reshape(-1) @ r.reshape(-1)
        if reg is not None:  # prior + limits: half-gradient and diagonal half-Hessian
            rv, rg, hd = regularization_value_and_gradient(
                reg, model.length_scale, pose, init, normals
            )
            g = g + 0.5 * _flat(rg)
            h = h + jnp.diag(jnp.concatenate([hd.reshape(-1), jnp.zeros(3, h.dtype)]))
            obj = obj + rv
        return obj, g * sv, h * (sv[:, None] * sv[None, :])

    z0 = _flat(init) / sv
    obj0, g0, h0 = lin(z0)
    one = jnp.asarray(1.0, z0.dtype)
    hmax = jnp.maximum(jnp.max(jnp.diagonal(h0)), jnp.finfo(z0.dtype).tiny)
    eye = jnp.eye(z0.shape[0], dtype=z0.dtype)
    done0 = obj0 <= abs_obj
    # carry: z, g, H, obj, mu, nu, step, done, status
    init_c = (
        z0,
        g0,
        h0,
        obj0,
        _LM_TAU * hmax,
        2.0 * one,
        jnp.asarray(0),
        done0,
        jnp.where(done0, _CONVERGED, _MAX_STEPS),
    )

    def cond(c):
        return (c[6] < max_steps) & ~c[7]

    def body(c):
        z, g, h, obj, mu, nu, step, _, _ = c
        chol = jnp.linalg.cholesky(h + mu * eye)
        dz = jax.scipy.linalg.cho_solve((chol, True), -g)
        zn = z + dz
        objn, gn, hn = lin(zn)
        pred = -(2.0 * g @ dz + dz @ h @ dz)
        rho = (obj - objn) / jnp.maximum(pred, jnp.finfo(z.dtype).tiny)
        ok = (objn < obj) & jnp.isfinite(objn) & jnp.all(jnp.isfinite(dz))
        z2 = jnp.where(ok, zn, z)
        o2 = jnp.where(ok, objn, obj)
        g2 = jnp.where(ok, gn, g)
        h2 = jnp.where(ok, hn, h)
        mu2 = jnp.where(ok, mu * jnp.maximum(_LM_DOWN, 1.0 - (2.0 * rho - 1.0) ** 3), mu * nu)
        mu2 = jnp.maximum(mu2, 1e-15 * hmax)
        nu2 = jnp.where(ok, 2.0, nu * 2.0)
        # a vanishing step is convergence only at a stationary point: every column of J
        # (nearly) orthogonal to the residual (MINPACK's gtol test), else the solver stalled
        dg = jnp.sqrt(jnp.maximum(jnp.diagonal(h2), 0.0) * jnp.maximum(o2, 0.0))
        stationary = jnp.all(jnp.abs(g2) <= 1e-8 * dg)
        small_step = jnp.max(jnp.abs(dz)) <= 1e-12
        conv = (
            (o2 <= abs_obj) | (ok & (obj - objn <= rtol * obj)) | (small_step & (ok | stationary))
        )
        stuck = ~jnp.isfinite(mu2) | (mu2 > 1e16 * hmax) | small_step
        status = jnp.where(conv, _CONVERGED, jnp.where(stuck, _STALLED, _MAX_STEPS))
        return (z2, g2, h2, o2, mu2, nu2, step + 1, conv | stuck, status)

    out = jax.lax.while_loop(cond, body, init_c)
    return _unflat(out[0] * sv, nj), out[6], out[8]


def _solve_bfgs(model, targets, init, max_steps, rtol, atol, gradient, reg, normals):
    """BFGS in scaled coordinates ``z = (θ, τ / L)``, backtracking Armijo line search.

    Each trial point costs one forward pass + one gradient of the chosen form (value and
    gradient together); the inverse Hessian ``H`` starts as ``0.1 / ‖∇E‖_∞ · I`` (first
    step: at most 0.1 rad), is rescaled by ``yᵀs / yᵀy`` after the first step and updated
    by ``H ← (I − ρ s yᵀ) H (I − ρ y sᵀ) + ρ s sᵀ`` (in its ``O(n²)`` form) when ``yᵀs > 0``.
    """
    nj = model.ancestors.shape[0]
    nk = targets.shape[0]
    scale = model.length_scale
    abs_obj = (atol * scale) ** 2 * nk
    n = 3 * nj + 3
    sv = jnp.concatenate([jnp.ones(3 * nj, targets.dtype), jnp.full(3, scale, targets.dtype)])

    def fg(z):
        pose = _unflat(z * sv, nj)
        v, g = _total(gradient, model, pose, targets, reg, init, normals)
        return v, _flat(g) * sv

    z0 = _flat(init) / sv
    f0, g0 = fg(z0)
    eye = jnp.eye(n, dtype=z0.dtype)
    c0 = 0.1 / jnp.maximum(jnp.max(jnp.abs(g0)), 1e-30)
    h0 = eye * c0
    done0 = f0 <= abs_obj
    c1 = 1e-4

    def line_search(z, f, g, d):
        gd = g @ d

        def cond(c):
            return ~c[3] & (c[4] < 30)

        def body(c):
            alpha, _, _, _, i = c
            fn, gn = fg(z + alpha * d)
            ok = jnp.isfinite(fn) & (fn <= f + c1 * alpha * gd) & jnp.all(jnp.isfinite(gn))
            return jnp.where(ok, alpha, 0.5 * alpha), fn, gn, ok, i + 1

        one = jnp.asarray(1.0, z.dtype)
        alpha, fn, gn, ok, _ = jax.lax.while_loop(cond, body, (one, f, g, jnp.asarray(False), 0))
        return alpha, fn, gn, ok

    # carry: z, f, g, H, step, done, status
    def cond(c):
        return (c[4] < max_steps) & ~c[5]

    def body(c):
        z, f, g, h, step, _, _ = c
        d = -h @ g
        descent = g @ d < 0
        d = jnp.where(descent, d, -c0 * g)  # not a descent direction: restart from H₀ = c₀ I
        alpha, fn, gn, ok = line_search(z, f, g, d)
        s = alpha * d
        y = gn - g
        ys = y @ s
        # the matrix the update starts from: H, or c₀ I after a restart, or (yᵀs / yᵀy) I
        # after the first step (one select of the n × n matrix per step)
        rescale = (step == 0) & (ys > 0)
        gamma = jnp.where(rescale, ys / jnp.maximum(y @ y, 1e-300), c0)
        h = jnp.where(~descent | rescale, eye * gamma, h)
        rho = 1.0 / jnp.where(ys > 0, ys, 1.0)
        hy = h @ y  # O(n²) form of (I − ρ s yᵀ) H (I − ρ y sᵀ) + ρ s sᵀ
        hn = h + (rho * rho * (y @ hy) + rho) * jnp.outer(s, s)
        hn = hn - rho * (jnp.outer(hy, s) + jnp.outer(s, hy))
        h2 = jnp.where(ok & (ys > 1e-12 * jnp.linalg.norm(s) * jnp.linalg.norm(y)), hn, h)
        z2 = jnp.where(ok, z + s, z)
        f2 = jnp.where(ok, fn, f)
        g2 = jnp.where(ok, gn, g)
        conv = ok & ((f2 <= abs_obj) | (f - f2 <= rtol * f))
        status = jnp.where(conv, _CONVERGED, jnp.where(ok, _MAX_STEPS, _STALLED))
        return z2, f2, g2, h2, step + 1, conv | ~ok, status

    init_c = (z0, f0, g0, h0, jnp.asarray(0), done0, jnp.where(done0, _CONVERGED, _MAX_STEPS))
    out = jax.lax.while_loop(cond, body, init_c)
    return _unflat(out[0] * sv, nj), out[4], out[6]


def _solve_optx(model, targets, init, max_steps, rtol, atol, method):
    import optimistix as optx

    def fn(pose, args):
        return ik_residuals(model, pose, targets)

    tol = dict(rtol=rtol, atol=atol * model.length_scale)
    solver = optx.LevenbergMarquardt(**tol) if method == "optx_lm" else optx.GaussNewton(**tol)
    sol = optx.least_squares(fn, solver, init, max_steps=max_steps, throw=False)
    ok = sol.result == optx.RESULTS.successful
    return sol.value, sol.stats["num_steps"], jnp.where(ok, _CONVERGED, _MAX_STEPS)


def _solve_adam(model, targets, init, max_steps, atol, gradient, learning_rate, reg, normals):
    import optax

    scale = model.length_scale
    nk = targets.shape[0]
    abs_obj = (atol * scale) ** 2 * nk
    opt = optax.adam(learning_rate)
    # optimise the translation in units of the mesh size, so one learning rate fits both blocks
    params0 = Pose(init.angles, init.translation / scale)
    state0 = opt.init(params0)

    def cond(c):
        return (c[2] < max_steps) & ~c[3]

    def body(c):
        params, state, step, _ = c
        pose = Pose(params.angles, params.translation * scale)
        obj, g = _total(gradient, model, pose, targets, reg, init, normals)
        g = Pose(g.angles, g.translation * scale)
        upd, state = opt.update(g, state, params)
        params = optax.apply_updates(params, upd)
        # converged when the objective before this update was already below the tolerance
        return params, state, step + 1, obj <= abs_obj

    out = jax.lax.while_loop(cond, body, (params0, state0, jnp.asarray(0), jnp.asarray(False)))
    params, _, steps, conv = out
    pose = Pose(params.angles, params.translation * scale)
    return pose, steps, jnp.where(conv, _CONVERGED, _MAX_STEPS)


def _dispatch(model, targets, init, method, gradient, max_steps, rtol, atol, lr, reg, normals):
    if method == "lm":
        return _solve_lm(model, targets, init, max_steps, rtol, atol, reg, normals)
    if method == "bfgs":
        return _solve_bfgs(model, targets, init, max_steps, rtol, atol, gradient, reg, normals)
    if method in ("optx_lm", "optx_gn"):
        return _solve_optx(model, targets, init, max_steps, rtol, atol, method)
    return _solve_adam(model, targets, init, max_steps, atol, gradient, lr, reg, normals)


@partial(jax.jit, static_argnames=("method", "gradient", "max_steps"))
def _solve(model, targets, init, method, gradient, max_steps, rtol, atol, lr, reg, normals):
    """One frame; non-finite inputs skip the solve (status 2, the initial pose returned),
    a non-finite final iterate is replaced by the initial pose (status 2)."""
    finite_in = jnp.all(jnp.isfinite(targets)) & jnp.all(jnp.isfinite(_flat(init)))
    if normals is not None:
        finite_in = finite_in & jnp.all(jnp.isfinite(normals))

    def run():
        safe_t = jnp.where(finite_in, targets, 0.0)
        safe_n = None if normals is None else jnp.where(finite_in, normals, 0.0)
        pose, steps, status = _dispatch(
            model, safe_t, init, method, gradient, max_steps, rtol, atol, lr, reg, safe_n
        )
        return pose, jnp.asarray(steps, jnp.int32), jnp.asarray(status, jnp.int32)

    def skip():
        return init, jnp.asarray(0, jnp.int32), jnp.asarray(_NON_FINITE, jnp.int32)

    pose, steps, status = jax.lax.cond(finite_in, run, skip)
    steps, status = jnp.asarray(steps, jnp.int32), jnp.asarray(status, jnp.int32)
    finite_out = jnp.all(jnp.isfinite(_flat(pose)))
    pose = jax.tree_util.tree_map(lambda a, b: jnp.where(finite_out, a, b), pose, init)
    status = jnp.where(finite_out, status, _NON_FINITE)
    return _result(model, pose, targets, steps, status, reg, init, normals)


def _check(model: IKModel, targets, init, method, gradient, max_steps, reg, normals):
    if method not in METHODS:
        raise FxspaceError(f"method must be one of {METHODS}, got {method!r}")
    if gradient not in GRADIENTS:
        raise FxspaceError(f"gradient must be one of {GRADIENTS}, got {gradient!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
        raise FxspaceError(f"max_steps must be a positive integer, got {max_steps!r}")
    nk = model.marker_joints.shape[0]
    if targets.shape[-2:] != (nk, 3):
        raise FxspaceError(
            f"targets must have shape (..., {nk}, 3) for this model's {nk} markers, "
            f"got {targets.shape}"
        )
    if not jnp.issubdtype(targets.dtype, jnp.floating) or targets.dtype == jnp.float16:
        raise FxspaceError(f"targets must be float32 or float64, got dtype {targets.dtype}")
    nj = model.ancestors.shape[0]
    if init is not None and (init.angles.shape != (nj, 3) or init.translation.shape != (3,)):
        raise FxspaceError(f"init must be a Pose with angles ({nj}, 3) and translation (3,)")
    if reg is not None and not isinstance(reg, IKRegularization):
        raise FxspaceError("regularization must come from fxspace.mesh.ik_regularization(...)")
    if reg is not None and reg.corners is not None:
        if method in ("lm", "optx_lm", "optx_gn"):
            raise FxspaceError(
                f"the normal constraint needs a gradient-based method ('bfgs' or 'adam'), "
                f"got method={method!r}"
            )
        if normals is None:
            raise FxspaceError("the normal constraint needs target_normals (markers, 3)")
    elif reg is not None and method in ("optx_lm", "optx_gn"):
        raise FxspaceError(f"regularization is not supported by method={method!r}")
    if normals is not None and normals.shape != targets.shape:
        raise FxspaceError(
            f"target_normals must have the shape of targets {targets.shape}, got {normals.shape}"
        )


def _rest(model: IKModel, dtype) -> Pose:
    nj = model.ancestors.shape[0]
    return Pose(jnp.zeros((nj, 3), dtype), jnp.zeros((3,), dtype))


def _prepare(model, targets, init, method, gradient, max_steps, rtol, atol, lr, reg, normals):
    """Checked arguments of :func:`_solve` / :func:`_track` (shared by the public entry
    points): the default step bound, normals cast like the targets, rest-pose ``init``."""
    max_steps = _DEFAULT_STEPS.get(method, 50) if max_steps is None else max_steps
    normals = None if normals is None else jnp.asarray(normals, targets.dtype)
    _check(model, targets, init, method, gradient, max_steps, reg, normals)
    init = _rest(model, targets.dtype) if init is None else init
    return model, targets, init, method, gradient, max_steps, rtol, atol, lr, reg, normals


def solve_ik(
    model: IKModel,
    targets: Float[Array, "markers 3"],
    init: Pose | None = None,
    *,
    method: Method = DEFAULT_METHOD,
    gradient: Gradient = "factored",
    max_steps: int | None = None,
    rtol: float = 1e-6,
    atol: float = 1e-7,
    learning_rate: float = 0.02,
    regularization: IKRegularization | None = None,
    target_normals: Float[Array, "markers 3"] | None = None,
) -> IKResult:
    """Pose that brings the markers to ``targets``: ``argmin_θ E(θ)`` (eq. (1)), one frame.

    **Arguments:**

    - `model`: from :func:`fxspace.ik_model`.
    - `targets`: ``(K, 3)`` marker targets.
    - `init`: starting pose (default: the rest pose, a cold start as in the paper); pass
      the previous frame's pose to warm-start along an animation (:func:`track_ik`).
    - `method`: ``"lm"`` (the default: Levenberg–Marquardt on the analytic Jacobian),
      ``"bfgs"`` (quasi-Newton on ``gradient``), ``"optx_lm"`` / ``"optx_gn"``
      (optimistix, Jacobian by autodiff), ``"adam"`` (first-order, optax).
      **Why LM is the default:** measured on CesiumMan (19 joints, 120 markers, its walk,
      float64, one jitted call per frame; ``experiments/bench_ik.py``), LM reaches a mean
      vertex error of 3.4e-4 in about 13 iterations from rest (1.5–2.5 ms per frame);
      BFGS on eq. (13) needs about 675 gradient evaluations for the same vertex error
      (15–19 ms per frame) and at ``rtol=1e-3`` stops at 30× the vertex error. LM is
      faster at equal accuracy at every marker count measured, so it stays the default.
      BFGS is the paper's gradient-only setting, where eq. (13) pays off: naive and
      factored BFGS take identical steps and the factored one is about 3× faster per
      solved frame at 120 markers (2.6–3.7× over runs).
    - `gradient`: for ``"bfgs"`` and ``"adam"``: ``"factored"`` (eq. (13)),
      ``"naive"`` (eq. (9)) or ``"autodiff"``.
    - `max_steps`: iteration bound (default 200 for BFGS, 50 otherwise).
    - `rtol`: stop when an accepted step lowers the objective by less than ``rtol · E``
      (LM, BFGS), or the optimistix step tolerance.
    - `atol`: stop when the RMS marker residual is below ``atol × length_scale``.
    - `learning_rate`: Adam's step (radians; the translation is scaled by the mesh size).
    - `regularization`: optional regularisers from :func:`fxspace.mesh.ik_regularization`
      (joint-angle prior, joint limits: every method but optimistix; normal constraint:
      ``"bfgs"``/``"adam"``).
    - `target_normals`: ``(K, 3)`` unit target normals for the normal constraint.

    **Returns:** :class:`fxspace.IKResult` (pose, RMS residual, objective, ``num_steps``,
    ``converged``, ``status``). Targets or an initial pose with NaN/inf give
    ``converged=False``, ``status=2`` and the initial pose. Jitted (the method, gradient
    and ``max_steps`` are static); vmappable over targets.

    Example: ``res = fx.solve_ik(model, targets); res.pose, bool(res.converged)``.
    """
    targets = jnp.asarray(targets)
    return _solve(
        *_prepare(
            model,
            targets,
            init,
            method,
            gradient,
            max_steps,
            rtol,
            atol,
            learning_rate,
            regularization,
            target_normals,
        )
    )


@partial(jax.jit, static_argnames=("method", "gradient", "max_steps"))
def _track(model, targets, init, method, gradient, max_steps, rtol, atol, lr, reg, normals):
    def step(pose, xs):
        tgt, nrm = xs
        res = _solve(model, tgt, pose, method, gradient, max_steps, rtol, atol, lr, reg, nrm)
        return res.pose, res

    _, out = jax.lax.scan(step, init, (targets, normals))
    return out


def track_ik(
    model: IKModel,
    targets: Float[Array, "frames markers 3"],
    init: Pose | None = None,
    *,
    method: Method = DEFAULT_METHOD,
    gradient: Gradient = "factored",
    max_steps: int | None = None,
    rtol: float = 1e-6,
    atol: float = 1e-7,
    learning_rate: float = 0.02,
    regularization: IKRegularization | None = None,
    target_normals: Float[Array, "frames markers 3"] | None = None,
) -> IKResult:
    """:func:`solve_ik` frame by frame along ``targets``, each frame warm-started from the last.

    One ``lax.scan``; returns an :class:`fxspace.IKResult` whose fields have a leading
    frame axis. Keyword arguments as :func:`solve_ik` (``target_normals`` then has a
    leading frame axis too). A frame with NaN targets keeps the previous pose (status 2)
    and the next frame starts from there.
    """
    targets = jnp.asarray(targets)
    if targets.ndim != 3:
        raise FxspaceError(f"targets must be (frames, markers, 3), got shape {targets.shape}")
    return _track(
        *_prepare(
            model,
            targets,
            init,
            method,
            gradient,
            max_steps,
            rtol,
            atol,
            learning_rate,
            regularization,
            target_normals,
        )
    )
