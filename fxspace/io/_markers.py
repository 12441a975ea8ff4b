"""``MarkerSequence`` (marker trajectories) and ``read_markers`` / ``write_npz``.

A marker sequence is ``positions`` of shape ``(T, M, 3)`` (frames, markers, xyz) with
NaN wherever a marker is missing (occluded, C3D negative residual, empty TRC cell):
missing is never 0. ``read_markers`` picks the format from the file name (``.c3d``,
``.trc``, ``.trc.gz``, ``.npz``); every reader raises
:class:`~fxspace.errors.CorruptFileError` naming the file and what is wrong.
"""

from __future__ import annotations

import dataclasses
import io
import zipfile
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from jaxtyping import Bool, Float, Int

from ..errors import CorruptFileError, FxspaceError
from ..runs import save_npz_atomic

__all__ = [
    "MarkerSequence",
    "read_markers",
    "write_npz",
    "SUPPORTED_EXTENSIONS",
    "UNIT_SCALES",
]

#: File name endings ``read_markers`` understands.
SUPPORTED_EXTENSIONS = (".c3d", ".trc", ".trc.gz", ".npz")

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


# -- NPZ ---------------------------------------------------------------------------------
_NPZ_KEYS = ("positions", "names", "rate", "units")


def write_npz(path: str | Path, seq: MarkerSequence) -> Path:
    """Write ``seq`` to ``path`` (``.npz``, compressed, atomic; keys positions, names, rate, units).

    Round-trips exactly (dtype included) with :func:`read_markers`.
    """
    _check_seq(seq)
    p = Path(path)
    if not p.name.lower().endswith(".npz"):
        raise FxspaceError(f"path must end with .npz, got {p.name!r}")
    return save_npz_atomic(
        p,
        positions=seq.positions,
        names=np.array(seq.names, dtype=str),
        rate=np.float64(seq.rate),
        units=np.array(seq.units),
    )


def _read_npz(path: Path) -> MarkerSequence:
    data = path.read_bytes()
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            missing = [k for k in _NPZ_KEYS if k not in z.files]
            if missing:
                raise CorruptFileError(
                    f"{path}: NPZ marker file lacks the key(s) {missing} "
                    f"(needs {list(_NPZ_KEYS)}; it has {sorted(z.files)})"
                )
            arrays = {k: z[k] for k in _NPZ_KEYS}
    except CorruptFileError:
        raise
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError) as e:
        raise CorruptFileError(f"{path}: not a readable NPZ file ({e})") from e
    try:
        names = tuple(str(n) for n in np.atleast_1d(arrays["names"]).tolist())
        rate = float(arrays["rate"])
        units = str(arrays["units"])
        return MarkerSequence(arrays["positions"], names, rate, units)
    except (TypeError, ValueError) as e:
        raise CorruptFileError(f"{path}: invalid marker data in NPZ file ({e})") from e


# -- dispatch ----------------------------------------------------------------------------
def _check_seq(seq: object) -> None:
    if not isinstance(seq, MarkerSequence):
        raise FxspaceError(
            f"seq must be a MarkerSequence, got {type(seq).__name__}; "
            "build one with MarkerSequence(positions, names, rate, units)"
        )


def _format_of(path: Path) -> str:
    name = path.name.lower()
    for ext in (".trc.gz", ".trc", ".c3d", ".npz"):
        if name.endswith(ext):
            return ext
    raise FxspaceError(
        f"cannot read {path}: unknown marker file extension; supported: "
        f"{', '.join(SUPPORTED_EXTENSIONS)}"
    )


def read_markers(path: str | Path) -> MarkerSequence:
    """Read a marker file: ``.c3d``, ``.trc``, ``.trc.gz`` or ``.npz`` → :class:`MarkerSequence`.

    - **C3D** (via the ``c3d`` package): rate from the header, units from
      ``POINT:UNITS``, names from ``POINT:LABELS`` (stripped); points with a negative
      residual (invalid) are NaN, never 0. Analog channels are ignored.
    - **TRC** (OpenSim / Motion Analysis text, tab separated; ``.trc.gz`` gzipped): rate
      from ``DataRate``, units from ``Units``; empty cells are NaN.
    - **NPZ**: keys ``positions``, ``names``, ``rate``, ``units`` (see :func:`write_npz`).

    Positions are float64, except NPZ which keeps the stored dtype.

    **Raises:** ``FileNotFoundError`` when ``path`` does not exist; ``ValueError`` for an
    unknown extension; :class:`~fxspace.errors.CorruptFileError` (naming the file, and the
    line for text files) for truncated or malformed files.
    """
    p = Path(path)
    fmt = _format_of(p)
    if not p.is_file():
        raise FileNotFoundError(f"marker file not found: {p}")
    if fmt == ".c3d":
        from ._c3d import _read_c3d

        return _read_c3d(p)
    if fmt in (".trc", ".trc.gz"):
        from ._trc import _read_trc

        return _read_trc(p)
    return _read_npz(p)
