"""Time: registration curves, incremental time-warping (eq. 1) and the clock alignment of
eqs. (2)–(3) of Ha & Han, "Decoupled parametric motion synthesis based on blending", §3.1.

Reference time ``T`` is measured in frames of a set's reference clip (the first example
``M_1``); ``C_i(T)`` maps it to the frame of example ``i`` (``warps[i]`` sampled at
``T = 0..N-1``, non-decreasing). With ``λ`` the alignment curve from lower reference frames
to upper reference frames:

- eq. (1): ``ΔT = (Σ_i w_i · dT/dC_i) · Δt`` with ``dT/dC_i = 1 / C_i'(T)`` — the weighted
  mean of the *inverse* warp slopes (`advance_clock`);
- eq. (2), generalised by the paper to ``0 ≤ α ≤ 1``: ``T_U ← α·λ(T_L) + (1−α)·T_U``
  (``α = ½`` is eq. (2) as printed);
- eq. (3): ``T_L ← λ⁻¹(T_U)`` — the lower clock is reset from the upper one
  (`align_clocks`).

Both clocks advance by non-negative increments before the alignment, so after it they never
run backwards either (the paper's argument, §3.1). The older duration-averaging increment
``Δt / Σ_i w_i C_i'(T)`` is kept as `advance_clock_duration` and the older clock update
as `sync_clocks` (deprecated: not the paper's equations).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.motion._blend import warp_times

__all__ = [
    "keytime_warp",
    "warp_slopes",
    "advance_clock",
    "advance_clock_duration",
    "align_clocks",
    "invert_curve",
    "Clocks",
    "sync_clocks",
    "interp_curve",
]


@checked
def keytime_warp(
    ref_keys: Float[Array, " K"], ex_keys: Float[Array, " K"], n_ref: int
) -> Float[Array, " n_ref"]:
    """Piecewise-linear warp through matching key times (``ref_keys[k] ↦ ex_keys[k]``),
    sampled at ``u = 0..n_ref-1``; both key lists increasing (e.g. start, impact, end)."""
    if isinstance(ref_keys, np.ndarray | list | tuple) and isinstance(
        ex_keys, np.ndarray | list | tuple
    ):
        return np.interp(
            np.arange(n_ref, dtype=np.float64),
            np.asarray(ref_keys, np.float64),
            np.asarray(ex_keys, np.float64),
        )
    u = jnp.arange(n_ref, dtype=jnp.result_type(float))
    return jnp.interp(u, jnp.asarray(ref_keys, u.dtype), jnp.asarray(ex_keys, u.dtype))


@checked
def interp_curve(curve: Float[Array, " N"], u: Float[Array, ""]) -> Float[Array, ""]:
    """Linear interpolation of a curve sampled at integer ``u`` (clamped)."""
    return warp_times(curve[None, :], u)[0]


@checked
def invert_curve(curve: Float[Array, " N"], y: Float[Array, ""]) -> Float[Array, ""]:
    """``λ⁻¹(y)`` for a non-decreasing curve ``λ`` sampled at ``u = 0..N-1`` and linear
    between samples: the ``u`` with ``λ(u) = y`` (``y`` clamped to ``[λ(0), λ(N-1)]``).

    On a flat piece (``λ`` constant over several samples) the *last* such ``u`` is
    returned, so ``λ⁻¹`` is non-decreasing in ``y``. Jittable; O(log N).

    Example: ``invert_curve(jnp.asarray([0., 2., 4.]), 3.0) == 1.5``.
    """
    n = curve.shape[0]
    yc = jnp.clip(y, curve[0], curve[-1])
    i = jnp.clip(jnp.searchsorted(curve, yc, side="right") - 1, 0, n - 2)
    d = curve[i + 1] - curve[i]
    s = jnp.where(d > 0, (yc - curve[i]) / jnp.where(d > 0, d, 1.0), 1.0)
    return i + jnp.clip(s, 0.0, 1.0)


@checked
def warp_slopes(warps: Float[Array, "E N"], u: Float[Array, ""]) -> Float[Array, " E"]:
    """``C_i'(u)``: slope of each sampled warp on the segment that contains ``u`` (NaN for
    a NaN ``u``: NaN in, NaN out)."""
    n = warps.shape[1]
    uu = jnp.asarray(u)
    i0 = jnp.clip(jnp.floor(jnp.where(jnp.isnan(uu), 0.0, uu)).astype(jnp.int32), 0, n - 2)
    return jnp.where(jnp.isnan(uu), jnp.nan, warps[:, i0 + 1] - warps[:, i0])


def _check_clock_args(w, dt, min_slope) -> None:
    """Concrete weights must be >= 0, ``dt`` > 0 and ``min_slope`` > 0 (NaN passes: NaN
    in gives NaN out); traced values pass."""
    if not isinstance(w, jax.core.Tracer) and np.any(np.asarray(w) < 0):
        raise FxspaceError(f"w must be >= 0 (blend weights), got {np.asarray(w).tolist()}")
    if not isinstance(dt, jax.core.Tracer) and np.any(np.asarray(dt) <= 0):
        raise FxspaceError(f"dt must be > 0 (real time per frame), got {dt!r}")
    if not isinstance(min_slope, jax.core.Tracer) and np.any(np.asarray(min_slope) <= 0):
        raise FxspaceError(f"min_slope must be > 0, got {min_slope!r}")


@checked
def advance_clock(
    u: Float[Array, ""],
    warps: Float[Array, "E N"],
    w: Float[Array, " E"],
    dt: float | Float[Array, ""] = 1.0,
    min_slope: float = 0.05,
) -> Float[Array, ""]:
    """Reference-time increment of eq. (1) (Ha & Han §3.1):
    ``ΔT = (Σ_i w_i · dT/dC_i) · Δt``.

    **Arguments:**

    - ``u``: the current reference time ``T`` (reference frames).
    - ``warps``: ``(E, N)`` the warps ``C_i`` sampled at reference frames ``0..N-1``.
    - ``w``: ``(E,)`` blend weights at this frame.
    - ``dt``: real time per animation frame, in example frames (1 when the output plays at
      the examples' frame rate).
    - ``min_slope``: ``C_i'`` is floored at this value (a flat piece of a DTW warp would
      make ``dT/dC_i`` infinite), so ``ΔT ≤ dt / min_slope``.

    **Returns:** ``ΔT ≥ 0`` (``> 0`` for ``dt > 0`` and non-negative weights summing to one).

    Example: two linear warps with slopes 0.5 and 2 and equal weights advance
    ``(0.5 · 2 + 0.5 · 0.5) · Δt = 1.25 Δt``.
    """
    _check_clock_args(w, dt, min_slope)
    inv = 1.0 / jnp.maximum(warp_slopes(warps, u), min_slope)
    return jnp.where(jnp.isnan(u), jnp.nan, jnp.einsum("e,e->", w, inv) * dt)  # NaN in, NaN out


@checked
def advance_clock_duration(
    u: Float[Array, ""],
    warps: Float[Array, "E N"],
    w: Float[Array, " E"],
    dt: float | Float[Array, ""] = 1.0,
    min_slope: float = 0.05,
) -> Float[Array, ""]:
    """The duration-averaging increment ``ΔT = Δt / max(Σ_i w_i C_i'(T), min_slope)`` (a
    harmonic mean of the inverse slopes): the blend plays the examples at one own-frame per
    output frame on average. **Not** the paper's eq. (1) (see `advance_clock`); kept
    as a named option for comparison. Two slopes 0.5 and 2 with equal weights give
    ``0.8 Δt``."""
    _check_clock_args(w, dt, min_slope)
    rate = jnp.einsum("e,e->", w, jnp.maximum(warp_slopes(warps, u), min_slope))
    return jnp.where(jnp.isnan(u), jnp.nan, dt / jnp.maximum(rate, min_slope))


@checked
def align_clocks(
    t_lower: Float[Array, ""],
    t_upper: Float[Array, ""],
    lam: Float[Array, " N"],
    alpha: float | Float[Array, ""] = 0.5,
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Eqs. (2)–(3) of Ha & Han §3.1: ``T_U ← α·λ(T_L) + (1−α)·T_U``, then
    ``T_L ← λ⁻¹(T_U)``.

    **Arguments:**

    - ``t_lower``, ``t_upper``: the two reference times after their eq.-(1) increments.
    - ``lam``: ``(N,)`` the alignment curve ``λ`` sampled at lower reference frames
      ``0..N-1`` (upper reference frames, non-decreasing), linear between samples;
      ``λ⁻¹`` inverts it (`invert_curve`).
    - ``alpha``: ``0 ≤ α ≤ 1``, the user's control (``α = ½`` is eq. (2) as printed;
      ``α = 1`` follows the lower body, ``α = 0`` the upper body).

    **Returns:** ``(t_lower, t_upper)``; ``t_upper`` is clamped to ``[λ(0), λ(N-1)]``.

    Example: ``λ(T) = 2T``, ``T_L = 3``, ``T_U = 4``, ``α = ½`` → ``T_U = 5``, ``T_L = 2.5``.
    """
    if not isinstance(alpha, jax.core.Tracer):
        a = np.asarray(alpha)
        if a.dtype.kind not in "iuf" or np.any(~((a >= 0) & (a <= 1)) & ~np.isnan(a)):
            raise FxspaceError(f"alpha must lie in [0, 1] (the user's control), got {alpha!r}")
    tu = alpha * interp_curve(lam, t_lower) + (1.0 - alpha) * t_upper  # eq. (2)
    tu = jnp.clip(tu, lam[0], lam[-1])
    return invert_curve(lam, tu), tu  # eq. (3)


class Clocks(NamedTuple):
    """The lower-body clock ``u`` and the upper-body clock ``v`` (reference frames)."""

    u: Float[Array, ""]
    v: Float[Array, ""]


@checked
def sync_clocks(
    clocks: Clocks,
    du: Float[Array, ""],
    dv_own: Float[Array, ""],
    lam: Float[Array, " N"],
    alpha: float | Float[Array, ""],
    v_max: float | Float[Array, ""],
) -> Clocks:
    """Deprecated: the earlier reconstruction of the clock synchronisation (use
    `align_clocks`, the paper's eqs. 2–3). Advances ``u`` by ``du`` and the upper
    clock ``v`` by the α-blend of the alignment curve's increment and its own increment
    ``dv_own``, then pulls ``v`` towards ``λ(u)`` with ``max()`` so it never decreases; the
    lower clock is never reset. Kept importable for old scripts."""
    u1 = clocks.u + du
    lam0, lam1 = interp_curve(lam, clocks.u), interp_curve(lam, u1)
    v_pred = clocks.v + alpha * jnp.maximum(lam1 - lam0, 0.0) + (1 - alpha) * dv_own
    v1 = jnp.maximum(clocks.v, v_pred + alpha * (lam1 - v_pred))
    return Clocks(u1, jnp.clip(v1, 0.0, v_max))
