"""Measurements of synthesised motion: foot sliding and ground speed."""

from __future__ import annotations

import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_indices, check_scalar

__all__ = ["foot_sliding", "ground_speed"]


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
