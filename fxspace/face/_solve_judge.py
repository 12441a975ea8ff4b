"""The quality judgement of `fxspace.face.solve_weights`, outside the jitted solve: each
frame's fit against the bound face's size (`_judge`), one more solve without a poor
frame's worst marker (`_retry_without_worst`), and the notes naming the poor frames, the
outlying markers and the markers that look swapped (`_notes`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.face._bind import Binding


def _retry_without_worst(solve, state, seen, few, dtype, size, ratio_j, fit_tol, outlier_tol):
    """One marker far off (a glitch) drags the whole frame's fit: leave each poor frame's
    worst marker out and solve again (``solve(v, w0)``); keep that where the rest then
    fits. ``state`` is ``(w, R, tau, rr, opt, steps, rms, fit, outl, poor)``; returns the
    updated state and the ``(T, M)`` mask of markers left out."""
    w, R, tau, rr, opt, steps, rms, fit, outl, poor = state
    dropped = np.zeros(seen.shape, bool)
    bad = np.flatnonzero(np.asarray(poor & ~few) & (seen.sum(axis=1) >= 5))
    if len(bad):
        worst = np.argmax(np.nan_to_num(np.asarray(rr)[bad], nan=-1.0), axis=1)
        drop = np.zeros(seen.shape, bool)
        drop[bad, worst] = True
        v2 = jnp.asarray(seen & ~drop, dtype)
        w2, R2, tau2, r2, opt2, obj2, steps2 = solve(v2, w)
        rr2 = jnp.where(jnp.asarray(seen) & ~few[:, None], r2, jnp.nan)
        kept = jnp.where(jnp.asarray(drop), jnp.nan, rr2)
        _, _, outl2, poor2 = _judge(kept, seen & ~drop, size, ratio_j, fit_tol, outlier_tol)
        take = np.zeros(len(seen), bool)
        take[bad] = ~np.asarray(poor2)[bad]
        if take.any():
            t = jnp.asarray(take)
            w, R, tau = (jnp.where(t[:, None], w2, w), jnp.where(t[:, None, None], R2, R),
                         jnp.where(t[:, None], tau2, tau))  # fmt: skip
            rr = jnp.where(t[:, None], rr2, rr)
            opt = jnp.where(t, opt2, opt)
            steps = jnp.where(t, steps + steps2, steps)
            rms, fit, outl, poor = _judge(jnp.where(jnp.asarray(drop), jnp.nan, rr), seen & ~drop,
                                          size, ratio_j, fit_tol, outlier_tol)  # fmt: skip
            dropped = drop & take[:, None]
            outl = outl | jnp.asarray(dropped)
            poor = poor | t
    return (w, R, tau, rr, opt, steps, rms, fit, outl, poor), dropped


def _judge(rr, seen, size: float, ratio, fit_tol: float, outlier_tol: float):
    """``(rms, fit, outliers, poor)`` of residuals ``rr`` ``(T, M)`` in rig units (NaN
    where not used) against the bound face's ``size``."""
    vs = jnp.asarray(seen, rr.dtype)
    rms = jnp.sqrt(jnp.nansum(rr * rr, axis=1) / jnp.maximum(vs.sum(axis=1), 1.0))
    fit = rms / size
    outl = jnp.nan_to_num(rr, nan=0.0) > outlier_tol * size
    off = (ratio < 0.67) | (ratio > 1.5)
    return rms, fit, outl, (fit > fit_tol) | jnp.any(outl, axis=1) | off


def _notes(b: Binding, fit, outl, ratio, few, fit_tol, outlier_tol, Y, seen, w, R, tau,
           A, rr, dropped) -> tuple[str, ...]:  # fmt: skip
    """One line per problem: the poor frames and the outlying markers, by name, and the
    markers that sit where another marker belongs (swapped or re-ordered)."""

    def frames(idx) -> str:
        idx = list(map(int, idx))
        return ", ".join(map(str, idx[:8])) + (f" … ({len(idx)} in all)" if len(idx) > 8 else "")

    notes = []
    big = np.flatnonzero((fit > fit_tol) & ~few)
    if len(big):
        notes.append(
            f"frames {frames(big)}: RMS residual up to {float(np.nanmax(fit[big])):.3g}× the "
            f"face's size (fit_tol {fit_tol:g})"
        )
    off = np.flatnonzero(((ratio < 0.67) | (ratio > 1.5)) & ~few)
    if len(off):
        notes.append(f"frames {frames(off)}: the markers' spread is {float(ratio[off[0]]):.3g}× "
                     "the neutral frame's (another unit, or not this face)")  # fmt: skip
    for t, m in zip(*np.nonzero(dropped), strict=True):
        notes.append(f"frame {int(t)}: marker {b.names[m]!r} is {rr[t, m] / b.scale:.4g} (capture "
                     f"units, {rr[t, m] / b.size:.3g}× the face's size) off the model: left "
                     "out of that frame's solve")  # fmt: skip
    worst = np.nanmax(np.where(outl, rr, np.nan), axis=0, initial=-np.inf)
    worst = np.where(outl.any(axis=0), worst, -np.inf)
    for m in np.argsort(-worst)[: min(5, int(outl.any(axis=0).sum()))]:
        notes.append(f"marker {b.names[m]!r} farther than {outlier_tol:g}× the face's size "
                     f"from the model in frames {frames(np.flatnonzero(outl[:, m]))}")  # fmt: skip
    if outl.any():  # which bound point each outlying marker sits at: swapped markers
        Af = np.asarray(A, np.float64).reshape(len(A), -1)
        P = np.asarray(b.points, np.float64)
        pairs: dict[tuple[int, int], int] = {}
        for t in np.flatnonzero(outl.any(axis=1) & ~few)[:200]:
            model = (P + (np.nan_to_num(w[t]) @ Af).reshape(-1, 3)) @ R[t].T + tau[t]
            for m in np.flatnonzero(outl[t]):
                d = np.linalg.norm(model - Y[t, m], axis=1)
                j = int(np.argmin(d))
                if j != m and d[j] < 0.5 * d[m]:  # nearer another's place than its own
                    pairs[(int(m), j)] = pairs.get((int(m), j), 0) + 1
        for (m, j), n in sorted(pairs.items(), key=lambda kv: -kv[1])[:5]:
            notes.append(f"marker {b.names[m]!r} sits where {b.names[j]!r} belongs in {n} "
                         "frame(s): swapped or re-ordered markers? pass names= to match by "
                         "name")  # fmt: skip
    return tuple(notes)
