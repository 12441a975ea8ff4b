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
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import check_choice
from fxspace.errors import FxspaceError
from fxspace.mesh._ik_constraints import IKConstraints, constraint_residuals
from fxspace.mesh._ik_methods import (
    BFGS,
    Adam,
    LevenbergMarquardt,
    OptimistixGaussNewton,
    OptimistixLM,
    Solver,
)
from fxspace.mesh._ik_model import IKModel, IKResult, ik_residuals
from fxspace.mesh._ik_problem import _flat, _iterate, _Problem
from fxspace.mesh._ik_regularizers import IKRegularization
from fxspace.mesh._skinning import Pose
from fxspace.results import check_result, result_from_flags

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "Method",
    "solver_from_method",
    "solve_ik",
    "track_ik",
]

Method = Literal["lm", "bfgs", "optx_lm", "optx_gn", "adam"]
METHODS: tuple[str, ...] = ("lm", "bfgs", "optx_lm", "optx_gn", "adam")
DEFAULT_METHOD: Method = "lm"


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
    nk = model.marker_joints.shape[0]
    want = "(frames, markers, 3)" if frames else "(markers, 3)"
    if not isinstance(targets, jax.Array):  # (jnp.asarray costs ~15 µs even on an Array)
        try:
            targets = jnp.asarray(targets)
        except (TypeError, ValueError) as e:
            raise FxspaceError(f"targets must be a numeric array {want} (the mesh's units, a "
                               f"row per marker), got {type(targets).__name__}: {e}") from None
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
