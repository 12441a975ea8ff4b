"""The one module that imports jaxopt (unmaintained upstream): swap it here, nowhere else.

It exposes the jaxopt solvers of `fxspace.fused_lasso`:

- the default path (``method="direct"``): jaxopt's ``ProximalGradient`` on
  ``½‖y − b‖² + g(b)`` with step 1 and the exact fused-lasso prox passed in by the caller
  (Condat's direct TV algorithm + soft-threshold) — one step from any start is
  ``prox_g(y)``, the exact solution, so it runs one step (`flsa_proximal_gradient`);
- ``method="dual"``: the box-constrained dual of the 1-D total-variation prox, solved with
  jaxopt's ``ProjectedGradient`` (accelerated projected gradient, i.e. FISTA on the dual);
- ``weights=``: the *weighted* fused lasso (weight 0 on missing frames), solved with
  jaxopt's ``ProximalGradient`` (FISTA) whose prox is the exact fused-lasso prox passed in
  by the caller (Condat's direct TV algorithm + soft-threshold).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float


def _jaxopt() -> tuple[Any, Callable]:
    """jaxopt and its box projection, imported on first use: jaxopt loads scipy.sparse,
    and ``import fxspace`` stays free of it (tests/test_dependencies.py)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import jaxopt
        from jaxopt.projection import projection_box
    return jaxopt, projection_box

__all__ = [
    "tv_dual_projected_gradient",
    "DualTVSolution",
    "weighted_proximal_gradient",
    "flsa_proximal_gradient",
]


class DualTVSolution(NamedTuple):
    """Primal/dual solution of the TV prox from the dual solver."""

    primal: Float[Array, "T C"]
    dual: Float[Array, "T-1 C"]
    num_steps: Array
    error: Array


def _dt(u: Array) -> Array:
    """Dᵀu for the forward-difference operator D (T-1×T), applied along axis 0."""
    z = jnp.zeros((1, *u.shape[1:]), u.dtype)
    return jnp.concatenate([z, u], axis=0) - jnp.concatenate([u, z], axis=0)


def tv_dual_projected_gradient(
    y: Float[Array, "T C"],
    lam: Float[Array, " C"],
    *,
    init: Float[Array, "T-1 C"] | None = None,
    maxiter: int = 20000,
    tol: float = 1e-10,
) -> DualTVSolution:
    """TV prox ``argmin_x ½‖y − x‖² + λ Σ_t |x_{t+1} − x_t|`` through its dual.

    Dual: ``min_u ½‖y − Dᵀu‖²`` s.t. ``|u_t| ≤ λ``; primal ``x = y − Dᵀu``. The dual is
    smooth with Lipschitz constant ``‖DDᵀ‖ ≤ 4`` (step 1/4), so accelerated projected
    gradient converges at O(1/k²) — exact in the limit but slow for long signals (the
    direct algorithm in `fxspace.controlpoints._fused_lasso` is the default).
    """
    if init is None:
        init = jnp.zeros((y.shape[0] - 1, *y.shape[1:]), y.dtype)

    def fun(u, y):
        r = y - _dt(u)
        return 0.5 * jnp.sum(r * r)

    jaxopt, projection_box = _jaxopt()
    pg = jaxopt.ProjectedGradient(
        fun=fun,
        projection=projection_box,
        stepsize=0.25,
        maxiter=maxiter,
        tol=tol,
        acceleration=True,
        implicit_diff=False,
        jit=True,
    )
    lo = -jnp.broadcast_to(lam, init.shape)
    sol = pg.run(init, hyperparams_proj=(lo, -lo), y=y)
    u = sol.params
    return DualTVSolution(y - _dt(u), u, sol.state.iter_num, sol.state.error)


def weighted_proximal_gradient(
    y: Float[Array, "T C"],
    w: Float[Array, "T C"],
    prox: Callable[[Array, float], Array],
    *,
    init: Float[Array, "T C"],
    maxiter: int,
    tol: float,
) -> tuple[Array, Array, Array]:
    """``argmin_b ½ Σ w (y − b)² + g(b)`` by jaxopt's accelerated ``ProximalGradient``.

    `prox(v, η)` must return ``prox_{η g}(v)``. The smooth part has Lipschitz constant
    ``max w``, so the step is ``1 / max w``. Returns ``(b, num_steps, error)`` where
    `error` is jaxopt's fixed-point residual ``‖b − prox(b − η∇f(b))‖ / η``.
    """

    def fun(b, y, w):
        r = b - y
        return 0.5 * jnp.sum(w * r * r)

    lip = jnp.maximum(jnp.max(w), 1e-12)
    jaxopt, _ = _jaxopt()
    pg = jaxopt.ProximalGradient(
        fun=fun,
        prox=lambda v, hyper, scaling: prox(v, scaling),
        stepsize=lambda _: 1.0 / lip,
        maxiter=maxiter,
        tol=tol,
        acceleration=True,
        implicit_diff=False,
        jit=True,
    )
    sol = pg.run(init, None, y=y, w=w)
    return sol.params, sol.state.iter_num, sol.state.error


def flsa_proximal_gradient(
    y: Float[Array, "T C"], prox: Callable[[Array, Array], tuple[Array, Any]], aux_init: Any
) -> tuple[Array, Any, Array]:
    """``argmin_b ½‖y − b‖² + g(b)`` by jaxopt's ``ProximalGradient`` with step 1.

    `prox(v, η)` returns ``(prox_{η g}(v), aux)`` — the exact prox, whose diagnostics
    (`aux`, a pytree of arrays of ``y``'s dtype shaped like `aux_init`) ride along as
    parameters that the smooth part ignores. The smooth part ``½‖y − b‖²`` has
    Lipschitz constant 1, so one step from ``b = y`` is ``prox_g(y)``: the exact solution,
    and jaxopt is asked for exactly one step. Returns ``(b, aux, num_steps)``.
    """

    def fun(params, y):
        r = params[0] - y
        return 0.5 * jnp.sum(r * r)

    def prox_params(params, hyper, scaling):
        b, aux = prox(params[0], scaling)
        return (b, aux)

    jaxopt, _ = _jaxopt()
    pg = jaxopt.ProximalGradient(
        fun=fun,
        prox=prox_params,
        stepsize=1.0,
        maxiter=1,
        tol=0.0,
        acceleration=False,
        implicit_diff=False,
        jit=True,
    )
    sol = pg.run((y, aux_init), None, y=y)
    b, aux = sol.params
    return b, aux, sol.state.iter_num
