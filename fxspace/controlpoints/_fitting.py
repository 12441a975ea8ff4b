"""Gradient-based fitting of control-point trajectories and blending weights (optax).

The paper left the tuning open; here the control-point model of a segment is refined by
minimising its eq. (1) error plus a temporal smoothness term,

    J(R, w) = E(X, x̂(R, w)) / E₀ + α Σ_k Σ_t ‖R_k(t+1) − 2R_k(t) + R_k(t−1)‖² / S₀,

over the control points' non-linear parts ``R_k(t)`` (interior frames; zero at the key
frames) and the memberships ``w_i = softmax(ℓ_i)`` restricted to each vertex's
``support`` nearest control points (so the stored weights stay sparse). ``E₀`` is the
starting error and ``S₀`` the starting ``Σ‖R‖²`` (a dimensionless objective). Adam runs
``steps`` iterations in a ``lax.scan``.
"""

from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Array, ArrayLike, Float, Int

from fxspace._validate import check_int, check_scalar, checked
from fxspace.controlpoints._model import (
    ControlPointModel,
    _control_residuals,
    linear_interpolation,
    reconstruct,
    residual_trajectories,
)
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, check_result, result_from_flags

__all__ = ["FitResult", "refine_control_points", "fit_objective"]


class FitResult(NamedTuple):
    """Result of `refine_control_points`.

    **Fields:** ``model`` (refined `ControlPointModel`), ``losses`` ``(steps,)``,
    ``num_steps``, ``converged`` (relative change of the loss over the last tenth of the
    steps below ``tol``), ``error`` (eq. (1) of the refined model), ``result`` (a
    `fxspace.RESULTS` member), ``stats`` (``max_steps``, ``relative_change``).
    """

    model: ControlPointModel
    losses: Float[Array, " steps"]
    num_steps: Int[Array, ""]
    error: Float[Array, ""]
    result: Any = None
    stats: dict | None = None

    @property
    def converged(self):
        """``result == RESULTS.successful`` (derived, not stored)."""
        return self.result == RESULTS.successful


def _weights(logits: Array, support: Array, c: int) -> Array:
    w = jax.nn.softmax(logits, axis=1)  # (N, k)
    N = logits.shape[0]
    return jnp.zeros((N, c), logits.dtype).at[jnp.arange(N)[:, None], support].add(w)


def _second_diff(R: Array) -> Array:
    return R[:, 2:] - 2.0 * R[:, 1:-1] + R[:, :-2]


def fit_objective(
    X: Float[Array, "T N 3"],
    interior: Float[Array, "c T-2 3"],
    logits: Float[Array, "N k"],
    support: Int[Array, "N k"],
    smoothness: float,
    e0: float | Array,
    s0: float | Array,
) -> Array:
    """The objective ``J`` of the module docstring (eq. (1) / E₀ + α · roughness / S₀)."""
    c = interior.shape[0]
    z = jnp.zeros((c, 1, 3), interior.dtype)
    R = jnp.concatenate([z, interior, z], axis=1)  # (c, T, 3)
    W = _weights(logits, support, c)
    L = linear_interpolation(X[0], X[-1], X.shape[0])
    Xh = L + jnp.einsum("nk,ktd->tnd", W, R)
    E = jnp.sum((X - Xh) ** 2)
    return E / e0 + smoothness * jnp.sum(_second_diff(R) ** 2) / s0


@partial(jax.jit, static_argnums=(4, 5))
def _run(X, interior, logits, support, steps, fit_weights, lr, smoothness, e0, s0):
    opt = optax.adam(lr)
    params = (interior, logits)
    state = opt.init(params)

    def loss(p):
        lg = p[1] if fit_weights else jax.lax.stop_gradient(p[1])
        return fit_objective(X, p[0], lg, support, smoothness, e0, s0)

    def step(carry, _):
        p, s = carry
        val, g = jax.value_and_grad(loss)(p)
        upd, s = opt.update(g, s, p)
        return (optax.apply_updates(p, upd), s), val

    (params, _), losses = jax.lax.scan(step, (params, state), None, length=steps)
    return params, losses


@checked
def refine_control_points(
    X: Float[ArrayLike, "T N 3"],
    model: ControlPointModel,
    *,
    steps: int = 200,
    learning_rate: float = 0.02,
    smoothness: float = 1e-3,
    support: int = 3,
    fit_weights: bool = True,
    tol: float = 1e-3,
    throw: bool = False,
) -> FitResult:
    """Refine a control-point model by gradient descent (Adam) on eq. (1) + smoothness.

    **Arguments:**

    - `X`: ``(T, N, 3)`` the segment; `model`: a starting model (e.g. from
      `fxspace.fit_control_points`).
    - `steps`, `learning_rate`: Adam iterations and step (parameters are in units of the
      RMS residual, so the step is scale-free).
    - `smoothness`: α, weight of the second-difference roughness of the trajectories.
    - `support`: control points each vertex may blend (its nearest in trajectory space,
      its own cluster first); `fit_weights`: fit the memberships too (else only the
      trajectories).
    - `throw`: raise `fxspace.errors.FxspaceError` when the result is not ``successful``
      (NaN/inf in `X`, a non-finite loss, or the loss still changing after `steps`).

    **Returns:** `FitResult`. Cost per step O(T·N·c).
    """
    X = jnp.asarray(X)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 3:
        raise FxspaceError(f"X must be (frames >= 3, vertices, 3); got {X.shape}")
    c, T = model.controls.shape[:2]
    if X.shape[0] != T or X.shape[1] != model.first.shape[0]:
        raise FxspaceError(
            f"X {X.shape} does not match the model (T={T}, N={model.first.shape[0]})"
        )
    steps = check_int(steps, "steps", low=1)
    support = check_int(support, "support", low=1)
    learning_rate = check_scalar(learning_rate, "learning_rate", low=0.0, low_open=True)
    smoothness = check_scalar(smoothness, "smoothness", low=0.0)
    if not 1 <= support <= c:
        raise FxspaceError(f"support must be in [1, {c}] (control points); got {support}")
    R0 = _control_residuals(model.controls)  # (c, T, 3)
    scale = jnp.sqrt(jnp.mean(R0**2)) + 1e-12
    # support: own cluster + nearest other control points in trajectory space
    F = jnp.moveaxis(residual_trajectories(X), 1, 0).reshape(X.shape[1], -1) / scale
    Cf = R0.reshape(c, -1) / scale
    d = jnp.sum(F * F, 1)[:, None] - 2.0 * F @ Cf.T + jnp.sum(Cf * Cf, 1)[None, :]
    d = d.at[jnp.arange(F.shape[0]), model.labels].set(-jnp.inf)
    sup = jax.lax.top_k(-d, support)[1]  # (N, k), own label first
    w0 = jnp.take_along_axis(model.weights, sup, axis=1)
    logits = jnp.log(jnp.maximum(w0, 1e-3))
    interior = R0[:, 1:-1] / scale
    Xs = X / scale
    e0 = jnp.maximum(jnp.sum((Xs - _recon(Xs, interior, logits, sup)) ** 2), 1e-30)
    s0 = jnp.maximum(jnp.sum(interior**2), 1e-30)
    (interior, logits), losses = _run(
        Xs, interior, logits, sup, int(steps), bool(fit_weights), learning_rate, smoothness,
        e0, s0,
    )  # fmt: skip
    z = jnp.zeros((c, 1, 3), X.dtype)
    R = jnp.concatenate([z, interior, z], axis=1) * scale
    # controls with the model's key frames at their ends and the fitted non-linear part
    s = jnp.linspace(0.0, 1.0, T, dtype=X.dtype)[None, :, None]
    C = model.controls[:, :1] + s * (model.controls[:, -1:] - model.controls[:, :1]) + R
    W = _weights(logits, sup, c)
    W = jnp.where(W > 1e-4, W, 0.0)
    W = W / jnp.sum(W, axis=1, keepdims=True)
    new = model._replace(controls=C, weights=W)
    k = max(1, steps // 10)
    rel = jnp.abs(losses[-1] - losses[-k - 1 if steps > k else 0]) / jnp.maximum(losses[-1], 1e-30)
    err = jnp.sum((X - _recon_model(new)) ** 2)
    bad_in = ~jnp.all(jnp.isfinite(X))
    bad_out = ~jnp.all(jnp.isfinite(losses)) | ~jnp.isfinite(err)
    conv = (rel < tol) & ~bad_out & ~bad_in
    res = result_from_flags(converged=conv, nonfinite_input=bad_in, nonfinite_output=bad_out)
    stats = {"max_steps": jnp.int32(steps), "relative_change": rel}
    out = FitResult(new, losses, jnp.int32(steps), err, res, stats)
    return check_result(res, throw, "refine_control_points", out)


def _recon(Xs, interior, logits, sup):
    c = interior.shape[0]
    z = jnp.zeros((c, 1, 3), interior.dtype)
    R = jnp.concatenate([z, interior, z], axis=1)
    W = _weights(logits, sup, c)
    return linear_interpolation(Xs[0], Xs[-1], Xs.shape[0]) + jnp.einsum("nk,ktd->tnd", W, R)


def _recon_model(model: ControlPointModel) -> Array:
    return reconstruct(model)
