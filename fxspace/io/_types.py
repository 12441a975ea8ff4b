"""The marker data type: `MarkerSequence` (trajectories with NaN where missing).

It lives apart from the readers so that every reader (C3D, TRC, NPZ) and every user of
marker data imports it without importing the others (no cycles). A `MarkerSequence` is a
registered JAX pytree (leaf: ``positions``; names, rate and units are static).

**Units**: millimetres are the house unit. ``UNIT_SCALES`` lists the known length units
(``mm``, ``cm``, ``m``, ``in``, ``ft``) and `canonical_units` maps their spellings
(``"inch"``, ``"Millimeters"``…) to those keys. The readers convert a file in inches or
feet to millimetres and record the file's unit in ``file_units`` (`to_house_units`), so
an inch file is never read as millimetres.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence

import jax
import numpy as np
from jaxtyping import Bool, Float, Int

from fxspace._validate import check_int, check_scalar
from fxspace.errors import FxspaceError

__all__ = ["MarkerSequence", "UNIT_SCALES", "HOUSE_UNITS", "canonical_units", "to_house_units"]

#: Length units and their size in millimetres.
UNIT_SCALES = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "ft": 304.8}

#: The unit fxspace computes in; readers convert non-metric files to it.
HOUSE_UNITS = "mm"

_ALIASES = {
    "millimeter": "mm",
    "millimeters": "mm",
    "millimetre": "mm",
    "millimetres": "mm",
    "centimeter": "cm",
    "centimeters": "cm",
    "centimetre": "cm",
    "centimetres": "cm",
    "meter": "m",
    "meters": "m",
    "metre": "m",
    "metres": "m",
    "inch": "in",
    "inches": "in",
    '"': "in",
    "foot": "ft",
    "feet": "ft",
}


def canonical_units(units: str) -> str:
    """The ``UNIT_SCALES`` key of a length-unit spelling (``"Inches"`` → ``"in"``,
    ``"MM"`` → ``"mm"``); another string is returned stripped, unchanged."""
    u = units.strip()
    low = u.lower()
    if low in UNIT_SCALES:
        return low
    return _ALIASES.get(low, u)


@dataclasses.dataclass(frozen=True, eq=False)
class MarkerSequence:
    """Marker trajectories: ``positions (T, M, 3)``, ``names``, ``rate`` (Hz), ``units``.

    **Arguments:**

    - ``positions``: ``(T, M, 3)`` float32/float64 array (integers are cast to float64);
      NaN where a marker is missing. A marker with any NaN coordinate is missing as a
      whole (all three coordinates become NaN). The array is copied and made read-only.
    - ``names``: ``M`` unique, non-empty marker names.
    - ``rate``: frame rate in Hz, finite and > 0.
    - ``units``: length unit of ``positions`` (a ``UNIT_SCALES`` key such as ``"mm"`` or
      ``"in"``, spellings like ``"inches"`` are canonicalised, or any other non-empty
      string; only the known ones convert with `MarkerSequence.to_units`).
    - ``file_units``: the unit the file declared when a reader converted it (e.g.
      ``"in"`` for an inch file read as millimetres); ``None`` when not converted.

    Invalid arguments raise `fxspace.errors.FxspaceError` (a ``ValueError``) naming the
    argument.
    """

    positions: Float[np.ndarray, "frames markers 3"]
    names: tuple[str, ...]
    rate: float
    units: str = "mm"
    file_units: str | None = None

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions)
        if pos.ndim != 3 or pos.shape[2] != 3:
            raise FxspaceError(
                f"positions must have shape (frames, markers, 3), got {pos.shape}; "
                "reshape to (T, M, 3)"
            )
        if np.issubdtype(pos.dtype, np.integer):
            pos = pos.astype(np.float64)
        elif pos.dtype not in (np.float32, np.float64):
            raise FxspaceError(
                f"positions must be a float32 or float64 array, got dtype {pos.dtype}; "
                "convert with .astype(np.float64)"
            )
        pos = np.array(pos, copy=True, order="C")
        if np.isinf(pos).any():
            raise FxspaceError("positions contain ±inf; mark missing markers with NaN instead")
        partial = np.isnan(pos).any(axis=-1)
        pos[partial] = np.nan
        pos.setflags(write=False)

        if isinstance(self.names, str):
            raise FxspaceError("names must be a sequence of marker names, not one string")
        names = tuple(self.names)
        if not all(isinstance(n, str) for n in names):
            raise FxspaceError("names must all be str")
        if len(names) != pos.shape[1]:
            raise FxspaceError(
                f"names has {len(names)} entries but positions has {pos.shape[1]} markers; "
                "give one name per marker"
            )
        if any(not n for n in names):
            raise FxspaceError("names must be non-empty strings")
        if len(set(names)) != len(names):
            dup = sorted(n for n, c in Counter(names).items() if c > 1)
            raise FxspaceError(f"names must be unique; duplicated: {dup}")

        rate = check_scalar(self.rate, "rate", low=0.0, low_open=True)  # Hz
        if not isinstance(self.units, str) or not self.units.strip():
            raise FxspaceError(f"units must be a non-empty string such as 'mm', got {self.units!r}")
        fu = self.file_units
        if fu is not None and (not isinstance(fu, str) or not fu.strip()):
            raise FxspaceError(f"file_units must be None or a unit such as 'in', got {fu!r}")

        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "rate", rate)
        object.__setattr__(self, "units", canonical_units(self.units))
        object.__setattr__(self, "file_units", None if fu is None else canonical_units(fu))

    # -- shape ---------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        """Number of markers ``M``."""
        return int(self.positions.shape[1])

    @property
    def times(self) -> Float[np.ndarray, " frames"]:
        """Frame times in seconds, ``arange(T) / rate``."""
        return np.arange(self.n_frames) / self.rate

    def __repr__(self) -> str:
        return (
            f"MarkerSequence(n_frames={self.n_frames}, n_markers={self.n_markers}, "
            f"rate={self.rate:g}, units={self.units!r}, "
            + (f"file_units={self.file_units!r}, " if self.file_units else "")
            + f"dtype={self.positions.dtype}, "
            f"missing={int(self.missing_mask().sum())})"
        )

    # -- queries -------------------------------------------------------------------------
    def missing_mask(self) -> Bool[np.ndarray, "frames markers"]:
        """``(T, M)`` boolean: True where a marker is missing (NaN)."""
        return np.isnan(self.positions[..., 0])

    def index(self, names: str | Sequence[str]) -> Int[np.ndarray, " k"]:
        """Column indices of ``names`` (a name or a sequence of names)."""
        wanted = [names] if isinstance(names, str) else list(names)
        lookup = {n: i for i, n in enumerate(self.names)}
        unknown = [n for n in wanted if n not in lookup]
        if unknown:
            raise FxspaceError(
                f"names {unknown} are not markers of this sequence; available: {list(self.names)}"
            )
        return np.array([lookup[n] for n in wanted], dtype=np.int64)

    # -- transforms (all return new sequences) --------------------------------------------
    def select(self, names: Sequence[str]) -> MarkerSequence:
        """The markers ``names``, in that order (e.g. to align the order of two takes)."""
        if isinstance(names, str):
            names = [names]
        idx = self.index(names)
        return dataclasses.replace(self, positions=self.positions[:, idx], names=tuple(names))

    def slice(
        self, start: int | None = None, stop: int | None = None, step: int | None = None
    ) -> MarkerSequence:
        """Frames ``start:stop:step`` (Python slice rules); the rate becomes ``rate / step``."""
        step_ = 1 if step is None else check_int(step, "step")
        if step_ <= 0:
            raise FxspaceError(f"step must be a positive integer, got {step!r}")
        for arg, v in (("start", start), ("stop", stop)):
            if v is not None:
                check_int(v, arg)
        pos = self.positions[slice(start, stop, step_)]
        return dataclasses.replace(self, positions=pos, rate=self.rate / step_)

    def to_units(self, units: str) -> MarkerSequence:
        """The same sequence in ``units`` (a ``UNIT_SCALES`` key: ``"mm"``, ``"cm"``,
        ``"m"``, ``"in"``, ``"ft"``, or a spelling of one such as ``"inches"``)."""
        units = canonical_units(units) if isinstance(units, str) else units
        if units not in UNIT_SCALES:
            raise FxspaceError(f"units must be one of {sorted(UNIT_SCALES)}, got {units!r}")
        if self.units not in UNIT_SCALES:
            raise FxspaceError(
                f"cannot convert from unknown units {self.units!r}; known: {sorted(UNIT_SCALES)}"
            )
        if units == self.units:
            return self
        factor = UNIT_SCALES[self.units] / UNIT_SCALES[units]
        pos = (self.positions * factor).astype(self.positions.dtype)
        return dataclasses.replace(self, positions=pos, units=units)

    def drop_missing_frames(self) -> tuple[MarkerSequence, Int[np.ndarray, " kept"]]:
        """Frames where every marker is present, and their indices in this sequence.

        The returned sequence keeps ``rate`` (frames are no longer evenly spaced when
        some were dropped: use the indices for timing).
        """
        kept = np.flatnonzero(~self.missing_mask().any(axis=1))
        return dataclasses.replace(self, positions=self.positions[kept]), kept


def _flatten(seq: MarkerSequence):
    return (seq.positions,), (seq.names, seq.rate, seq.units, seq.file_units)


def _unflatten(aux, children) -> MarkerSequence:
    # no validation: under jax transformations the leaf is a tracer or a placeholder
    obj = object.__new__(MarkerSequence)
    for k, v in zip(("names", "rate", "units", "file_units"), aux, strict=True):
        object.__setattr__(obj, k, v)
    object.__setattr__(obj, "positions", children[0])
    return obj


jax.tree_util.register_pytree_node(MarkerSequence, _flatten, _unflatten)


def to_house_units(seq: MarkerSequence) -> MarkerSequence:
    """``seq`` in millimetres when it is in inches or feet (``file_units`` records the
    file's unit); metric and unknown units are kept (metric converts losslessly with
    `MarkerSequence.to_units`)."""
    if seq.units in ("in", "ft"):
        mm = seq.to_units(HOUSE_UNITS)
        return dataclasses.replace(mm, file_units=seq.file_units or seq.units)
    return seq


def _check_seq(seq: object) -> None:
    if not isinstance(seq, MarkerSequence):
        raise FxspaceError(
            f"seq must be a MarkerSequence, got {type(seq).__name__}; "
            "build one with MarkerSequence(positions, names, rate, units)"
        )
