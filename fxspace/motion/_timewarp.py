"""Time: registration curves, incremental time-warping and the two synchronised clocks.

Generic time ``u`` is measured in frames of a reference clip; ``C_i(u)`` maps it to the
frame of example ``i`` (sampled at ``u = 0..N-1``, non-decreasing). The equations of the
seed paper (Ha & Han) are implemented as follows (our reconstruction; the numbers refer
to the seed's equations):

- eq. (1), incremental time-warping: the blend advances so that the examples' own clocks
  advance one frame per output frame on average, ``Δu = Δt / Σ_i w_i C_i'(u)``; slopes are
  floored at ``min_slope > 0``, so ``Δu > 0`` — time never runs backwards.
- eq. (2), clock synchronisation: the upper-body clock ``v`` advances by
  ``Δv = α (λ(u + Δu) − λ(u)) + (1 − α) Δv_own`` where ``λ`` aligns the lower reference
  clip to the upper one and ``Δv_own`` is the upper space's own eq.-(1) increment.
- eq. (3), drift correction: ``v ← max(v, v_pred + α (λ(u + Δu) − v_pred))`` with
  ``v_pred = v + Δv`` from eq. (2): exactly ``v = λ(u)`` for ``α = 1``, the free-running
  clock for ``α = 0``, and never backwards for any α.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace.motion._blend import warp_times

__all__ = ["keytime_warp", "warp_slopes", "advance_clock", "Clocks", "sync_clocks", "interp_curve"]


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


def interp_curve(curve: Float[Array, " N"], u: Float[Array, ""]) -> Float[Array, ""]:
    """Linear interpolation of a curve sampled at integer ``u`` (clamped)."""
    return warp_times(curve[None, :], u)[0]


def warp_slopes(warps: Float[Array, "E N"], u: Float[Array, ""]) -> Float[Array, " E"]:
    """``C_i'(u)``: slope of each sampled warp on the segment that contains ``u``."""
    n = warps.shape[1]
    i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, n - 2)
    return warps[:, i0 + 1] - warps[:, i0]


def advance_clock(
    u: Float[Array, ""],
    warps: Float[Array, "E N"],
    w: Float[Array, " E"],
    dt: float = 1.0,
    min_slope: float = 0.05,
) -> Float[Array, ""]:
    """Generic-time increment of eq. (1): ``Δu = dt / max(Σ_i w_i C_i'(u), min_slope)`` ≥ 0."""
    rate = jnp.einsum("e,e->", w, jnp.maximum(warp_slopes(warps, u), min_slope))
    return dt / jnp.maximum(rate, min_slope)


class Clocks(NamedTuple):
    """The lower-body clock ``u`` and the upper-body clock ``v`` (reference frames)."""

    u: Float[Array, ""]
    v: Float[Array, ""]


def sync_clocks(
    clocks: Clocks,
    du: Float[Array, ""],
    dv_own: Float[Array, ""],
    lam: Float[Array, " N"],
    alpha: float | Float[Array, ""],
    v_max: float | Float[Array, ""],
) -> Clocks:
    """One step of eqs. (2)–(3): advance ``u`` by ``du`` and the upper clock ``v`` by the
    α-blend of the alignment curve ``λ`` (``lam`` sampled at lower reference frames) and its
    own increment ``dv_own``; ``v`` never decreases and stays in ``[0, v_max]``."""
    u1 = clocks.u + du
    lam0, lam1 = interp_curve(lam, clocks.u), interp_curve(lam, u1)
    v_pred = clocks.v + alpha * jnp.maximum(lam1 - lam0, 0.0) + (1 - alpha) * dv_own  # eq. (2)
    v1 = jnp.maximum(clocks.v, v_pred + alpha * (lam1 - v_pred))  # eq. (3)
    return Clocks(u1, jnp.clip(v1, 0.0, v_max))
