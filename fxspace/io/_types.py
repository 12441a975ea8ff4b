"""The marker data type: :class:`MarkerSequence` (trajectories with NaN where missing).

It lives apart from the readers so that every reader (C3D, TRC, NPZ) and every user of
marker data imports it without importing the others (no cycles).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence

import numpy as np
from jaxtyping import Bool, Float, Int

from fxspace.errors import FxspaceError

__all__ = ["MarkerSequence", "UNIT_SCALES"]

#: Length units and their size in millimetres.
UNIT_SCALES = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


@dataclasses.dataclass(frozen=True, eq=False)
class MarkerSequence:
    """Marker trajectories: ``positions (T, M, 3)``, ``names``, ``rate`` (Hz), ``units``.

    **Arguments:**

    - ``positions``: ``(T, M, 3)`` float32/float64 array (integers are cast to float64);
      NaN where a marker is missing. A marker with any NaN coordinate is missing as a
      whole (all three coordinates become NaN). The array is copied and made read-only.
    - ``names``: ``M`` unique, non-empty marker names.
    - ``rate``: frame rate in Hz, finite and > 0.
    - ``units``: length unit of ``positions`` (``"mm"``, ``"cm"``, ``"m"`` or any other
      non-empty string; only the three known ones convert with :meth:`to_units`).

    Invalid arguments raise :class:`~fxspace.errors.FxspaceError` (a ``ValueError``)
    naming the argument.
    """

    positions: Float[np.ndarray, "frames markers 3"]
    names: tuple[str, ...]
    rate: float
    units: str = "mm"

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

        try:
            rate = float(self.rate)
        except (TypeError, ValueError):
            raise FxspaceError(f"rate must be a number (Hz), got {self.rate!r}") from None
        if not np.isfinite(rate) or rate <= 0:
            raise FxspaceError(f"rate must be finite and > 0 (Hz), got {self.rate!r}")
        if not isinstance(self.units, str) or not self.units.strip():
            raise FxspaceError(f"units must be a non-empty string such as 'mm', got {self.units!r}")

        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "rate", rate)
        object.__setattr__(self, "units", self.units.strip())

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
            f"rate={self.rate:g}, units={self.units!r}, dtype={self.positions.dtype}, "
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
        return MarkerSequence(self.positions[:, idx], tuple(names), self.rate, self.units)

    def slice(
        self, start: int | None = None, stop: int | None = None, step: int | None = None
    ) -> MarkerSequence:
        """Frames ``start:stop:step`` (Python slice rules); the rate becomes ``rate / step``."""
        step_ = 1 if step is None else int(step)
        if step_ <= 0:
            raise FxspaceError(f"step must be a positive integer, got {step!r}")
        pos = self.positions[slice(start, stop, step_)]
        return MarkerSequence(pos, self.names, self.rate / step_, self.units)

    def to_units(self, units: str) -> MarkerSequence:
        """The same sequence in ``units`` (one of ``"mm"``, ``"cm"``, ``"m"``)."""
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
        return MarkerSequence(pos, self.names, self.rate, units)

    def drop_missing_frames(self) -> tuple[MarkerSequence, Int[np.ndarray, " kept"]]:
        """Frames where every marker is present, and their indices in this sequence.

        The returned sequence keeps ``rate`` (frames are no longer evenly spaced when
        some were dropped: use the indices for timing).
        """
        kept = np.flatnonzero(~self.missing_mask().any(axis=1))
        return MarkerSequence(self.positions[kept], self.names, self.rate, self.units), kept


def _check_seq(seq: object) -> None:
    if not isinstance(seq, MarkerSequence):
        raise FxspaceError(
            f"seq must be a MarkerSequence, got {type(seq).__name__}; "
            "build one with MarkerSequence(positions, names, rate, units)"
        )
