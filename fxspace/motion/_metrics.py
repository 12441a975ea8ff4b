"""Measurements of synthesised motion, read off the joints: foot sliding, ground speed,
cadence, the coupling of the upper body's cycle to the lower body's (Ha & Han Fig. 3) and
joint speeds."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_indices, check_scalar
from fxspace.errors import FxspaceError

__all__ = [
    "foot_sliding",
    "ground_speed",
    "CycleCoupling",
    "swing_signal",
    "cycle_events",
    "cycle_coupling",
    "cadence",
    "joint_speeds",
]


def foot_sliding(
    X: Float[Array, "T J 3"], feet: tuple[int, ...], rate: float, contact_height: float = 0.03
) -> float:
    """Mean horizontal speed (m/s) of the ``feet`` joints while they touch the ground: both
    ends of a frame step within ``contact_height`` of that joint's lowest height in the clip.
    Averaged over the feet that touch the ground at all; ``nan`` if none does. A clean
    capture slides a few cm/s; blending artefacts show up as more.

    Example: a foot standing still for the whole clip gives ``0.0``.
    """
    X = as_float_array(X, "X", shape=(None, None, 3), finite="allow", xp="numpy")
    X = X.astype(np.float64)
    feet = check_indices(feet, "feet", X.shape[1], min_len=1)
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    contact_height = check_scalar(contact_height, "contact_height", low=0.0)
    out = []
    for j in feet:
        p = X[:, j]
        h = p[:, 1]
        low = h.min() + contact_height
        contact = (h[1:] < low) & (h[:-1] < low)
        v = np.linalg.norm(np.diff(p[:, [0, 2]], axis=0), axis=1) * rate
        if contact.any():
            out.append(v[contact].mean())
    return float(np.mean(out)) if out else float("nan")


def ground_speed(root: Float[Array, "T 3"], rate: float) -> float:
    """Average ground speed (m/s): the horizontal path length of ``root`` over the clip's
    duration (``(T − 1) / rate`` seconds)."""
    r = as_float_array(root, "root", shape=(None, 3), finite="allow", xp="numpy")
    r = r.astype(np.float64)
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    if r.shape[0] < 2:
        return 0.0
    d = np.linalg.norm(np.diff(r[:, [0, 2]], axis=0), axis=1).sum()
    return float(d * rate / (r.shape[0] - 1))


class CycleCoupling(NamedTuple):
    """How an upper-body cycle keeps time with the lower body's (`cycle_coupling`).

    ``cycle_ratio``: mean upper cycle length / mean lower cycle length (1: both halves
    end their cycles together); ``phase_drift``: how fast the phase of the upper cycle at
    the lower body's stride events slips, in cycles per minute (absolute least-squares
    slope; 0: a steady phase relation, as in a capture); ``lower_period_s`` /
    ``upper_period_s``: the mean cycle lengths (s); ``lower_events`` / ``upper_events``:
    the event times (s); ``relative_phase``: the upper cycle's phase at each lower event,
    unwrapped (cycles). NaN where fewer than two events of a half were found."""

    cycle_ratio: float
    phase_drift: float
    lower_period_s: float
    upper_period_s: float
    lower_events: np.ndarray
    upper_events: np.ndarray
    relative_phase: np.ndarray


def swing_signal(
    X: Float[Array, "T J 3"], a: int, b: int, lateral: tuple[int, int]
) -> np.ndarray:
    """Forward offset (m) of joint ``a`` ahead of joint ``b`` in the body's own heading
    frame, per frame: forward is horizontal and perpendicular to the line through the
    ``lateral`` pair of joints (e.g. the two hips), read off the joints alone. Left foot
    against right foot gives one period per stride; right hand against left hand, the arm
    swing."""
    X = as_float_array(X, "X", shape=(None, None, 3), finite="allow", xp="numpy")
    X = X.astype(np.float64)
    a, b, l0, l1 = check_indices((a, b, *lateral), "a, b, lateral", X.shape[1], min_len=4)
    side = (X[:, l0] - X[:, l1]) * np.array([1.0, 0.0, 1.0])
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-12)
    fwd = np.cross(side, np.array([0.0, 1.0, 0.0]))  # left × up = forward (y up)
    return np.einsum("tc,tc->t", X[:, a] - X[:, b], fwd)


def _moving_mean(s: np.ndarray, n: int) -> np.ndarray:
    """Mean over a window of ``n`` frames (shortened to the signal; NaN frames skipped)."""
    k = np.ones(min(max(n, 1), s.size))
    num = np.convolve(np.where(np.isfinite(s), s, 0.0), k, mode="same")
    den = np.convolve(np.isfinite(s).astype(float), k, mode="same")
    return num / np.maximum(den, 1.0)


def cycle_events(
    signal, rate: float, hysteresis: float = 0.3, window_s: float = 2.0
) -> np.ndarray:
    """Times (s) at which a roughly periodic ``signal`` crosses its local mean upward, one
    per cycle. Mean and amplitude are local (moving over ``window_s`` seconds, so a walk
    whose swing grows or shrinks — a sad walk's small arm swing — keeps every cycle): a
    crossing counts only after the signal went below ``−hysteresis ×`` the local RMS and
    is confirmed when it passes ``+hysteresis ×`` it (noise near the mean is no cycle);
    the time is interpolated linearly between the two frames around the crossing."""
    s = as_float_array(signal, "signal", xp="numpy").astype(np.float64)
    if s.ndim != 1:
        raise FxspaceError(f"signal must be 1-D (one value per frame), got shape {s.shape}")
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    hysteresis = check_scalar(hysteresis, "hysteresis", low=0.0)
    window_s = check_scalar(window_s, "window_s", low=0.0, low_open=True)
    ok = np.isfinite(s)
    if ok.sum() < 3:
        return np.zeros(0)
    n = int(round(window_s * rate))
    s = s - _moving_mean(s, n)
    h = hysteresis * np.sqrt(_moving_mean(s**2, n))
    out, armed, cand = [], False, None
    for t in range(1, s.size):
        if not (ok[t] and ok[t - 1]):
            armed, cand = False, None
            continue
        if s[t] < -h[t]:
            armed, cand = True, None
        elif armed and cand is None and s[t - 1] < 0 <= s[t]:
            cand = t - 1 + (-s[t - 1]) / (s[t] - s[t - 1])
        if armed and cand is not None and s[t] > h[t]:
            out.append(cand / rate)
            armed, cand = False, None
    return np.asarray(out)


def _period(ev: np.ndarray) -> float:
    return float((ev[-1] - ev[0]) / (ev.size - 1)) if ev.size >= 2 else float("nan")


def _pair(v, name: str) -> tuple[int, int]:
    if isinstance(v, str | bytes) or not hasattr(v, "__len__") or len(v) != 2:
        raise FxspaceError(f"{name} must be a (left, right) pair of joint indices, got {v!r}")
    try:
        return int(v[0]), int(v[1])
    except (TypeError, ValueError):
        raise FxspaceError(f"{name} must hold two joint indices (ints), got {v!r}") from None


def cycle_coupling(
    X: Float[Array, "T J 3"],
    feet: tuple[int, int],
    hands: tuple[int, int],
    lateral: tuple[int, int],
    rate: float,
) -> CycleCoupling:
    """Ha & Han Fig. 3 read off the joints: the lower body's strides (left foot against
    right foot, `swing_signal`, one `cycle_events` per stride) against the upper body's
    arm swing (right hand against left hand), over the span both are seen.

    ``feet``, ``hands``: (left, right) joint indices; ``lateral``: (left, right) joints
    across the pelvis (the hips) that define forward. Example: a captured walk gives a
    ``cycle_ratio`` near 1 and a ``phase_drift`` near 0; an upper body played on its own
    clock over a lower body of another tempo drifts by the difference of their cadences.
    """
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    feet, hands, lateral = _pair(feet, "feet"), _pair(hands, "hands"), _pair(lateral, "lateral")
    lo = cycle_events(swing_signal(X, feet[0], feet[1], lateral), rate)
    up = cycle_events(swing_signal(X, hands[1], hands[0], lateral), rate)
    nan = float("nan")
    if lo.size < 2 or up.size < 2:
        return CycleCoupling(nan, nan, _period(lo), _period(up), lo, up, np.zeros(0))
    inside = lo[(lo >= up[0]) & (lo <= up[-1])]
    j = np.clip(np.searchsorted(up, inside, side="right") - 1, 0, up.size - 2)
    phase = j + (inside - up[j]) / (up[j + 1] - up[j])  # upper cycles elapsed at each stride
    rel = phase - np.arange(inside.size)
    if rel.size >= 2:
        slope = np.polyfit(inside, rel, 1)[0] if rel.size >= 3 else (rel[-1] - rel[0]) / (
            inside[-1] - inside[0])  # fmt: skip
        drift = abs(float(slope)) * 60.0
    else:
        drift = nan
    pl, pu = _period(lo), _period(up)
    return CycleCoupling(pu / pl, drift, pl, pu, lo, up, rel)


def cadence(X: Float[Array, "T J 3"], feet: tuple[int, int], lateral: tuple[int, int],
            rate: float) -> float:  # fmt: skip
    """The lower body's cadence read off the feet: strides (left-foot cycles) per second,
    from the first to the last stride event of `swing_signal` (left foot against right);
    NaN with fewer than two strides."""
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    feet, lateral = _pair(feet, "feet"), _pair(lateral, "lateral")
    ev = cycle_events(swing_signal(X, feet[0], feet[1], lateral), rate)
    return 1.0 / _period(ev) if ev.size >= 2 else float("nan")


def joint_speeds(X: Float[Array, "T J 3"], rate: float, height: float = 1.0) -> np.ndarray:
    """Each joint's largest speed over a clip, ``(J,)``, in ``height`` per second (body
    heights per second with the body's height): frame-to-frame displacement × rate."""
    X = as_float_array(X, "X", shape=(None, None, 3), finite="allow", xp="numpy")
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    height = check_scalar(height, "height", low=0.0, low_open=True)
    v = np.linalg.norm(np.diff(X.astype(np.float64), axis=0), axis=-1) * rate / height
    return np.nanmax(v, axis=0) if v.shape[0] else np.full(X.shape[1], np.nan)
