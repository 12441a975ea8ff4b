"""The unit checks every marker reader shares: a marker array's size (`marker_extent`),
the length unit that size suggests (`infer_units`), and `check_units_plausible`, which
warns when a face or body has an implausible size for its declared unit, naming the
likely unit and the fix. Read by `fxspace.io.read_markers` through the table reader
(`fxspace.io._table` re-exports them).
"""

from __future__ import annotations

import math

import numpy as np

from fxspace._progress import note
from fxspace.io._types import UNIT_SCALES, MarkerSequence

__all__ = ["marker_extent", "infer_units", "check_units_plausible"]

#: Per-frame extents (mm) plausible for a captured face or body: a face spans about
#: 150–300 mm, a body 1–2.5 m; outside [30 mm, 5 m] a unit label is likely wrong.
_PLAUSIBLE_MM = (30.0, 5000.0)


def marker_extent(positions: np.ndarray) -> float | None:
    """The markers' size: the median over frames of the diagonal of the box that holds a
    frame's present markers (frames with at least 2 markers), in the positions' units;
    ``None`` when no frame has 2 markers."""
    pos = np.asarray(positions, np.float64)
    ok = np.isfinite(pos).all(axis=-1)
    good = ok.sum(axis=1) >= 2
    if not good.any():
        return None
    p = np.where(ok[..., None], pos, np.nan)[good]
    diag = np.linalg.norm(np.nanmax(p, axis=1) - np.nanmin(p, axis=1), axis=-1)
    diag = diag[np.isfinite(diag)]
    return float(np.median(diag)) if diag.size else None


def infer_units(positions: np.ndarray) -> tuple[str, str]:
    """``(unit, why)``: the length unit a marker array's extent suggests (``marker_extent``:
    under 5 → ``"m"``, 5–50 → ``"cm"`` (a face in cm), else ``"mm"`` (a face in mm, or a
    body in cm — said in ``why``; declare the units to be sure)."""
    e = marker_extent(positions)
    if e is None:
        return "mm", "no frame holds two markers, so mm is assumed"
    if e < 5.0:
        unit = "m"
    elif e < 50.0:
        unit = "cm"
    else:
        unit = "mm"
    why = f"a frame spans {e:.3g} (median)"
    if unit == "mm" and e < 400.0:
        why += " — a face in mm, or a body in cm"
    return unit, why


def _likely_unit(extent_mm: float) -> str:
    """The unit that brings an implausible extent (read in mm) nearest a face or body."""
    best, best_d = "mm", math.inf
    for u in ("mm", "cm", "m", "in"):
        mm = extent_mm * UNIT_SCALES[u]  # the values, read as u instead of mm
        lo, hi = 100.0, 2500.0
        d = 0.0 if lo <= mm <= hi else min(abs(math.log(mm / lo)), abs(math.log(mm / hi)))
        if d < best_d:
            best, best_d = u, d
    return best


def check_units_plausible(seq: MarkerSequence, source: str) -> bool:
    """Warn (`note`, ``warning=True``) when ``seq``'s markers have an implausible size for
    their declared unit (a frame spanning under 30 mm or over 5 m), naming the likely
    unit and the fix (``units=`` / ``[data] units``). Returns whether the size is
    plausible (True when it cannot be judged: unknown units, < 2 markers)."""
    if seq.units not in UNIT_SCALES:
        return True
    e = marker_extent(seq.positions)
    if e is None or e == 0.0:
        return True
    mm = e * UNIT_SCALES[seq.units]
    lo, hi = _PLAUSIBLE_MM
    if lo <= mm <= hi:
        return True
    values_mm = e  # the numbers themselves, as if they were mm
    likely = _likely_unit(values_mm)
    if likely == seq.units:
        return True
    note(
        f"{source}: the markers span {e:.3g} {seq.units} per frame (median) — implausible "
        f"for a face or a body in {seq.units}; the values look like {likely} "
        f"({e * UNIT_SCALES[likely]:.3g} mm). If they are, read them with "
        f"units={likely!r} (a config: [data] units = {likely!r})",
        warning=True,
    )
    return False
