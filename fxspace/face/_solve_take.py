"""The take `fxspace.face.solve_weights` is given, checked against the binding before
solving: the markers as ``(T, M, 3)`` in the binding's order (matched by name when names
are known), the solver's numbers, the take's units converted to the binding's, and a take
whose size is not the bound neutral frame's (another unit) refused with the fix.
"""

from __future__ import annotations

import difflib

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.face._bind import Binding, _check_unique, _units_arg
from fxspace.face._rig import Rig
from fxspace.io import UNIT_SCALES


def _take_markers(rig, binding, markers, names, units):
    """``(X, single, units)``: the markers as ``(T, M, 3)`` float64 in the binding's
    marker order (``single`` when one frame was passed), after checking the rig and the
    binding; a `MarkerSequence`'s names and units fill in ``names`` and ``units``."""
    if not isinstance(rig, Rig) or not isinstance(binding, Binding):
        raise FxspaceError("pass a fx.face.Rig and the fx.face.Binding from bind_markers")
    if hasattr(markers, "positions") and hasattr(markers, "names"):  # a MarkerSequence
        names = markers.names if names is None else names
        units = getattr(markers, "units", None) if units is None else units
        markers = markers.positions
    X = np.asarray(markers, np.float64)
    single = X.ndim == 2
    X = X[None] if single else X
    M = len(binding.names)
    if names is not None:
        X = _by_name(X, names, binding.names)
    if X.ndim != 3 or X.shape[1:] != (M, 3) or len(X) < 1:
        raise FxspaceError(f"markers must be (frames, {M}, 3) for this binding; got {X.shape}")
    if binding.basis.shape[0] != rig.num_shapes:
        raise FxspaceError("binding was made for another rig (shape count differs); bind again")
    return X, single, units


def _check_numbers(*, temporal, ridge, tol, fit_tol, outlier_tol, outer, inner) -> None:
    """Refuse a non-finite or negative tolerance or weight, and iteration counts that are
    not integers >= 1."""
    checks = (("temporal", temporal, 0.0), ("ridge", ridge, 0.0), ("tol", tol, 0.0),
              ("fit_tol", fit_tol, 0.0), ("outlier_tol", outlier_tol, 0.0))  # fmt: skip
    for name, val, low in checks:
        if not (np.isfinite(val) and val >= low):
            raise FxspaceError(f"{name} must be a finite number >= {low}; got {val!r}")
    for name, val in (("outer", outer), ("inner", inner)):
        if not isinstance(val, (int, np.integer)) or val < 1:
            raise FxspaceError(f"{name} must be an integer >= 1; got {val!r}")


def _near(name: str, options) -> list[str]:
    low = {str(o).lower(): str(o) for o in options}
    hits = difflib.get_close_matches(name.lower(), list(low), n=3, cutoff=0.6)
    return [low[h] for h in hits]


def _by_name(X: np.ndarray, names, bound: tuple[str, ...]) -> np.ndarray:
    """The take's markers in the binding's order, matched by name."""
    names = tuple(str(n) for n in names)
    if X.ndim != 3 or X.shape[1] != len(names):
        raise FxspaceError(f"names must give one name per marker ({X.shape[1]}); got {len(names)}")
    _check_unique(names)
    pos = {n: i for i, n in enumerate(names)}
    missing = [n for n in bound if n not in pos]
    extra = [n for n in names if n not in set(bound)]
    if missing or extra:
        hint = "; ".join(f"{n!r}: near {_near(n, names)}" for n in missing[:3] if _near(n, names))
        raise FxspaceError(
            f"the take's markers are not the binding's: missing {missing[:5]}, unknown "
            f"{extra[:5]}"
            + (f" ({hint})" if hint else "")
            + "; rename them, or bind this take (fx.face.bind_markers)"
        )
    return X[:, [pos[n] for n in bound]]


def _convert_units(X: np.ndarray, units, bound_units) -> np.ndarray:
    try:
        u = _units_arg(units)
    except FxspaceError:
        u = None  # an unknown label: the size check below decides
    if u is None or bound_units is None or u == bound_units:
        return X
    return X * (UNIT_SCALES[u] / UNIT_SCALES[bound_units])


def _size_ratio(Y: np.ndarray, seen: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per frame, the RMS radius of the seen markers over the neutral's (same markers):
    1 for a take at the binding's scale, 0.001 for a take in m bound in mm."""
    v = seen.astype(np.float64)[..., None]
    n = np.maximum(v.sum(axis=1), 1.0)
    cy = (v * Y).sum(axis=1) / n
    cp = (v * P[None]).sum(axis=1) / n
    ry = (v * (Y - cy[:, None]) ** 2).sum(axis=(1, 2))
    rp = (v * (P[None] - cp[:, None]) ** 2).sum(axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.sqrt(ry / rp)
    return np.where(seen.sum(axis=1) >= 3, out, np.nan)


def _check_size(ratio: np.ndarray, units, bound_units) -> None:
    """Refuse a take whose size is not the neutral frame's (another unit)."""
    good = ratio[np.isfinite(ratio)]
    if not len(good):
        return
    med = float(np.median(good))
    if 0.5 <= med <= 2.0:
        return
    guess = {1000.0: "mm → m", 100.0: "cm → m", 10.0: "mm → cm", 25.4: "mm → in",
             304.8: "mm → ft", 2.54: "cm → in", 30.48: "cm → ft", 3.28084: "ft → m"}  # fmt: skip
    f = 1.0 / med if med < 1 else med
    best = min(guess, key=lambda g: abs(np.log(f / g)))
    a, b = guess[best].split(" → ")
    like = f"bound in {a}, solved in {b}" if med < 1 else f"bound in {b}, solved in {a}"
    said = f"; the take says units={units!r}, the binding {bound_units!r}" if units else ""
    raise FxspaceError(
        f"the take is {med:.3g}× the size of the neutral frame it was bound to (like "
        f"{like}){said}: solve in the binding's units (MarkerSequence.to_units), or pass "
        "units= to bind_markers and solve_weights so the take is converted"
    )
