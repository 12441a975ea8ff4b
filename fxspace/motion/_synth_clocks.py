"""The clocks of decoupled synthesis (Ha & Han, eqs. (1)–(3)): eq. (1) per example set,
the alignment of eqs. (2)–(3) bounded by `clock_bounds`, their periodic form for a session
that walks on, and the tempo they predict (`clock_cycle_rate`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace._validate import check_scalar, checked
from fxspace.motion._synth_types import SynthesisSpaces, SynthState
from fxspace.motion._timewarp import (
    advance_clock,
    align_clocks,
    interp_curve,
    invert_curve,
    warp_slopes,
)

__all__ = ["clock_bounds", "clock_cycle_rate"]


@checked
def clock_bounds(sp: SynthesisSpaces, t_lower, t_upper, dt=1.0):
    """The bound on eqs. 2–3 (``sp.max_clock_rate``, ``r``): the largest advance each clock
    may make in one frame, ``r · max_i Δt / max(C_i'(T), min_slope)`` over the examples
    ``i`` of its own set at its own phase ``T`` — the eq.-(1) advance of the fastest
    captured example there. Eq. (1)'s own advance (a weighted mean over the same
    examples) never exceeds it, so the bound only holds back what the alignment adds:
    α keeps its effect (a body half may take the other half's tempo) as long as some
    captured clip of that half moved that fast. ``inf`` (eqs. 2–3 as printed): no bound.

    **Returns:** ``(bound_lower, bound_upper)`` in reference frames per output frame."""
    ms = sp.min_slope

    def fastest(warps, t):
        return jnp.max(1.0 / jnp.maximum(warp_slopes(warps, t), ms)) * dt

    r = sp.max_clock_rate
    return r * fastest(sp.lower.warps, t_lower), r * fastest(sp.upper.warps, t_upper)


def _advance(sp: SynthesisSpaces, state: SynthState, wL, wU, alpha, dt, wrap: bool):
    """Step 5: eq. (1) for each set, then eqs. (2)–(3) bounded by `clock_bounds`
    (``sp.aligned = False``: eq. 1 only). ``wrap=False`` stops ``T_L`` at the lower
    reference clip's end; ``wrap=True`` wraps it (and ``T_U`` by the span of ``λ``) so the
    cycle repeats. Returns ``(t_lower, t_upper, wrapped)``."""
    ms = sp.min_slope
    end = sp.lam.shape[0] - 1.0
    dl = advance_clock(state.t_lower, sp.lower.warps, wL, dt, ms)  # eq. 1
    du = advance_clock(state.t_upper, sp.upper.warps, wU, dt, ms)
    tl, tu = state.t_lower + dl, state.t_upper + du
    # the bound: after eqs. 2–3 neither clock runs faster than the fastest example of
    # its own set at its phase (rushing a body past every capture is the pop it cures)
    cap = None
    if sp.max_clock_rate != float("inf"):
        bl, bu = clock_bounds(sp, state.t_lower, state.t_upper, dt)
        cap = (state.t_lower + jnp.maximum(bl, dl), state.t_upper + jnp.maximum(bu, du))
    if wrap:
        if not sp.aligned:
            return _wrap_apart(sp.lam, tl, tu)
        return _align_periodic(sp.lam, tl, tu, alpha, cap)
    wrapped = jnp.zeros((), bool)
    tl = jnp.minimum(tl, end)
    if not sp.aligned:
        return tl, jnp.minimum(tu, sp.lam[-1]), wrapped
    tl, tu = align_clocks(tl, tu, sp.lam, alpha)  # eqs. 2–3
    if cap is not None:
        tl, tu = _capped(tl, tu, cap, lambda t: interp_curve(sp.lam, t),
                         lambda y: invert_curve(sp.lam, y))  # fmt: skip
    return tl, tu, wrapped


def _wrap_apart(lam, tl, tu):
    """Fig. 3(a): each clock wraps at the end of its own reference cycle (``N − 1`` and
    ``λ(N−1)``), never aligned; ``wrapped`` follows the lower clock."""
    P = lam.shape[0] - 1.0
    S = jnp.maximum(lam[-1] - lam[0], 1e-9)
    k = jnp.maximum(jnp.floor(tl / P), 0.0)
    ku = jnp.maximum(jnp.floor((tu - lam[0]) / S), 0.0)
    return tl - k * P, tu - ku * S, k > 0


def _capped(tl, tu, cap, lam, inv):
    """The aligned clocks ``(tl, tu)`` (``tl = λ⁻¹(tu)``) held to their caps: ``tu`` at
    most ``cap[1]`` (``tl`` follows by eq. 3), then ``tl`` at most ``cap[0]`` (``tu``
    follows by ``λ``), so the pair stays aligned."""
    over_u = tu > cap[1]
    tu = jnp.where(over_u, cap[1], tu)
    tl = jnp.where(over_u, inv(tu), tl)
    over_l = tl > cap[0]
    return jnp.where(over_l, cap[0], tl), jnp.where(over_l, lam(cap[0]), tu)


def _align_periodic(lam, tl, tu, alpha, cap=None):
    """Eqs. (2)–(3) on the periodic extension of ``λ`` (``λ(T + P) = λ(T) + S`` with
    ``P = N − 1`` and ``S = λ(N−1) − λ(0)``), then both clocks wrapped by the same number of
    cycles: a clock past its cycle's end keeps its phase relation to the other."""
    P = lam.shape[0] - 1.0
    S = jnp.maximum(lam[-1] - lam[0], 1e-9)

    def lam_ext(t):
        k = jnp.floor(t / P)
        return interp_curve(lam, t - k * P) + k * S

    def inv_ext(y):
        k = jnp.floor((y - lam[0]) / S)
        return invert_curve(lam, y - k * S) + k * P

    tu = alpha * lam_ext(tl) + (1.0 - alpha) * tu  # eq. (2)
    tl = inv_ext(tu)  # eq. (3)
    if cap is not None:  # the rate cap (see `_advance`)
        tl, tu = _capped(tl, tu, cap, lam_ext, inv_ext)
    k = jnp.maximum(jnp.floor(tl / P), 0.0)
    return tl - k * P, tu - k * S, k > 0


@checked
def clock_cycle_rate(
    sp: SynthesisSpaces,
    lower_weights: Float[Array, " EL"],
    upper_weights: Float[Array, " EU"],
    alpha: float | Float[Array, ""] = 0.5,
    n_frames: int = 600,
    dt: float = 1.0,
) -> Float[Array, ""]:
    """What eqs. (1)–(3) predict for the lower body's tempo, from the clocks alone (no
    pose): lower reference cycles per output frame over ``n_frames`` frames of the
    periodic clocks (`locomotion`'s), both blends held fixed, with the spaces' bound
    (`clock_bounds`; ``max_clock_rate = inf`` for eqs. 2–3 as printed). ``α = 1`` gives
    the lower blend's own eq.-(1) tempo, ``α = 0`` the upper blend's mapped through
    ``λ`` (where the bound allows it). Jittable; O(n_frames)."""
    check_step_controls(alpha, dt)
    return _clock_cycle_rate(sp, lower_weights, upper_weights, alpha, n_frames, dt)


@functools.partial(jax.jit, static_argnums=(4,))
def _clock_cycle_rate(sp, wL, wU, alpha, n_frames, dt):
    dtype = sp.lam.dtype
    wL, wU = jnp.asarray(wL, dtype), jnp.asarray(wU, dtype)
    alpha = jnp.asarray(alpha, dtype)
    z = jnp.zeros((), dtype)
    st0 = SynthState(z, sp.lam[0] + z, jnp.zeros(len(sp.lower_dims), dtype),
                     sp.upper_params, wL)  # fmt: skip

    def body(c, _):
        st, cycles = c
        tl, tu, wrapped = _advance(sp, st, wL, wU, alpha, dt, wrap=True)
        return (st._replace(t_lower=tl, t_upper=tu), cycles + wrapped), None

    (st, cycles), _ = jax.lax.scan(body, (st0, z), None, length=n_frames)
    return (cycles + st.t_lower / (sp.lam.shape[0] - 1.0)) / n_frames


def check_step_controls(alpha, dt) -> None:
    """Refuse an ``alpha`` outside ``[0, 1]`` or a negative / non-finite ``dt`` (concrete
    values only; traced ones are checked by the NaN pose)."""
    check_scalar(alpha, "alpha", low=0.0, high=1.0)
    check_scalar(dt, "dt", low=0.0)
