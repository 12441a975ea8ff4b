"""Occluded markers as a first-class input: fill short gaps in time, report the rest.

A real capture loses markers for 1 to 100+ frames at a time (a hand in front of the face,
a marker leaving the cameras' view). fxspace never turns a missing marker into a number:
`fill_gaps` interpolates each marker's trajectory across gaps of at most
``max_gap`` frames and leaves the longer ones NaN, listing them, so the caller can drop
those frames (`fxspace.clean_frames`) or stop with an error naming the markers and
frames (`fxspace.expression.require_complete`).

Interpolation (per marker, per coordinate, across one gap ``[a, b]`` with the samples
``x(a−1)`` and ``x(b+1)`` present):

- ``"linear"``: ``x(t) = x(a−1) + (t − a + 1)/(b − a + 2) · (x(b+1) − x(a−1))``;
- ``"cubic"``: the cubic Hermite curve between the same two samples with tangents from
  one-sided finite differences (``x(a−1) − x(a−2)`` and ``x(b+2) − x(b+1)``, zero where
  those samples are missing) — smooth velocity across short gaps.

Gaps touching the first or last frame have only one side and are never extrapolated.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, NamedTuple

import numpy as np

from fxspace._validate import as_float_array, check_choice, check_int, describe_missing
from fxspace._validate import missing_report as _runs
from fxspace.errors import FxspaceError

__all__ = ["GapFill", "fill_gaps", "missing_report", "require_complete"]


class GapFill(NamedTuple):
    """Result of `fill_gaps`.

    - `positions`: ``(T, M, 3)``, gaps of at most `max_gap` frames filled, longer gaps
      (and gaps touching the first or last frame) left NaN.
    - `filled`: ``(T, M)`` bool, True where a value was interpolated.
    - `unfilled`: the gaps left NaN, ``[(marker, first_frame, last_frame), ...]``
      (0-based, inclusive), markers named as passed in `marker_names`.
    - `max_gap`: the longest gap that was filled, in frames.
    """

    positions: np.ndarray
    filled: np.ndarray
    unfilled: list[tuple[str, int, int]]
    max_gap: int

    @property
    def complete_frames(self) -> np.ndarray:
        """Indices of the frames with every marker present after filling."""
        return np.flatnonzero(np.isfinite(self.positions).all(axis=(1, 2)))


def missing_report(
    positions, marker_names: Sequence[str] | None = None
) -> list[tuple[str, int, int]]:
    """Every gap of every marker, ``[(marker, first_frame, last_frame), ...]``.

    A marker is missing in a frame when any of its coordinates is NaN. Frames are 0-based
    and inclusive.
    """
    pos = as_float_array(positions, "positions", shape=(None, None, 3), finite="nan", xp="numpy")
    return _runs(pos, marker_names)


def require_complete(positions, marker_names: Sequence[str] | None = None) -> None:
    """Raise a `fxspace.errors.FxspaceError` naming the missing markers and frames.

    Does nothing when every marker is present in every frame.
    """
    runs = missing_report(positions, marker_names)
    if runs:
        n = len({m for m, *_ in runs})
        raise FxspaceError(
            f"positions has {len(runs)} gaps on {n} markers: {describe_missing(runs)}; "
            "fill them (fxspace.fill_gaps / [data] missing = 'fill') or drop the frames "
            "([data] missing = 'drop')"
        )


def _runs_with_index(pos: np.ndarray, names):
    """`missing_report` runs paired with their marker index."""
    out = []
    for m in range(pos.shape[1]):
        sub = _runs(pos[:, m : m + 1], None if names is None else [names[m]])
        out.extend((r, m) for r in sub)
    return [((f"marker {m}" if names is None else r[0], r[1], r[2]), m) for r, m in out]


def _hermite(p0, p1, m0, m1, s):
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * p0
        + (s3 - 2 * s2 + s) * m0
        + (-2 * s3 + 3 * s2) * p1
        + (s3 - s2) * m1
    )


def fill_gaps(
    positions,
    max_gap: int = 10,
    *,
    method: Literal["linear", "cubic"] = "linear",
    marker_names: Sequence[str] | None = None,
) -> GapFill:
    """Fill each marker's gaps of at most `max_gap` frames by interpolation in time.

    **Arguments:**
    - `positions`: ``(T, M, 3)`` marker positions, NaN where a marker is missing (a marker
      with any NaN coordinate counts as missing in that frame).
    - `max_gap`: the longest gap (consecutive missing frames) to fill; longer gaps stay NaN
      and are listed in the result. ``0`` fills nothing.
    - `method`: ``"linear"`` or ``"cubic"`` (Hermite, see the module docstring).
    - `marker_names`: names used in the report (default ``"marker <m>"``).

    **Returns:** a `GapFill` with `.positions`, `.filled` ``(T, M)`` and `.unfilled`.
    Cost O(T·M).

    **Example:**

    ```python
    res = fx.fill_gaps(seq.positions, max_gap=30)
    res.positions, res.filled.sum(), res.unfilled      # [(marker, first, last), ...]
    ```
    """
    pos = as_float_array(positions, "positions", shape=(None, None, 3), finite="nan", xp="numpy")
    max_gap = check_int(max_gap, "max_gap", low=0)
    check_choice(method, "method", ("linear", "cubic"))
    T, M, _ = pos.shape
    if marker_names is not None and len(marker_names) != M:
        raise FxspaceError(f"marker_names has {len(marker_names)} names for {M} markers")
    out = pos.copy()
    out[~np.isfinite(pos).all(axis=2)] = np.nan
    present = np.isfinite(out).all(axis=2)
    filled = np.zeros((T, M), dtype=bool)
    unfilled: list[tuple[str, int, int]] = []
    for (label, a, b), m in _runs_with_index(out, marker_names):
        inner = a > 0 and b < T - 1
        if not inner or b - a + 1 > max_gap:
            unfilled.append((label, a, b))
            continue
        x0, x1 = out[a - 1, m], out[b + 1, m]
        s = ((np.arange(a, b + 1) - (a - 1)) / (b - a + 2))[:, None]
        if method == "linear":
            out[a : b + 1, m] = x0 + s * (x1 - x0)
        else:
            span = b - a + 2  # frames from a−1 to b+1
            v0 = x0 - out[a - 2, m] if a >= 2 and present[a - 2, m] else np.zeros(3)
            v1 = out[b + 2, m] - x1 if b + 2 < T and present[b + 2, m] else np.zeros(3)
            out[a : b + 1, m] = _hermite(x0, x1, v0 * span, v1 * span, s)
        filled[a : b + 1, m] = True
    return GapFill(out, filled, unfilled, max_gap)
