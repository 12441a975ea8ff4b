"""``MarkerSequence`` (marker trajectories) and ``read_markers`` / ``write_npz``.

A marker sequence is ``positions`` of shape ``(T, M, 3)`` (frames, markers, xyz) with
NaN wherever a marker is missing (occluded, C3D negative residual, empty TRC cell):
missing is never 0. ``read_markers`` picks the format from the file name (``.c3d``,
``.trc``, ``.trc.gz``, ``.npz``); every reader raises
`CorruptFileError` naming the file and what is wrong.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from fxspace._validate import check_readable, checked
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._c3d import _read_c3d
from fxspace.io._trc import _read_trc
from fxspace.io._types import UNIT_SCALES, MarkerSequence, _check_seq, to_house_units
from fxspace.runs import save_npz_atomic

__all__ = [
    "MarkerSequence",
    "read_markers",
    "write_npz",
    "SUPPORTED_EXTENSIONS",
    "UNIT_SCALES",
]

#: File name endings ``read_markers`` understands.
SUPPORTED_EXTENSIONS = (".c3d", ".trc", ".trc.gz", ".npz")

# -- NPZ ---------------------------------------------------------------------------------
_NPZ_KEYS = ("positions", "names", "rate", "units")


def write_npz(path: str | Path, seq: MarkerSequence) -> Path:
    """Write ``seq`` to ``path`` (``.npz``, compressed, atomic; keys positions, names, rate, units).

    Round-trips exactly (dtype included) with `read_markers`.
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
def _format_of(path: Path) -> str:
    name = path.name.lower()
    for ext in (".trc.gz", ".trc", ".c3d", ".npz"):
        if name.endswith(ext):
            return ext
    raise FxspaceError(
        f"cannot read {path}: unknown marker file extension; supported: "
        f"{', '.join(SUPPORTED_EXTENSIONS)}"
    )


@checked
def read_markers(path: str | Path) -> MarkerSequence:
    """Read a marker file: ``.c3d``, ``.trc``, ``.trc.gz`` or ``.npz`` → `MarkerSequence`.

    - **C3D** (via the ``c3d`` package): rate from the header, units from
      ``POINT:UNITS``, names from ``POINT:LABELS`` (stripped); points with a negative
      residual (invalid) are NaN, never 0. Analog channels are ignored.
    - **TRC** (OpenSim / Motion Analysis text, tab separated; ``.trc.gz`` gzipped): rate
      from ``DataRate``, units from ``Units``; empty cells are NaN.
    - **NPZ**: keys ``positions``, ``names``, ``rate``, ``units`` (see `write_npz`).

    **Units**: a file in inches or feet is converted to millimetres (the house unit):
    ``seq.units == "mm"`` and ``seq.file_units`` records the file's unit (``"in"``);
    metric files keep their unit (``seq.to_units("mm")`` converts them).

    Positions are float64, except NPZ which keeps the stored dtype.

    **Raises:** ``FileNotFoundError`` when ``path`` does not exist; ``ValueError`` for an
    unknown extension; `CorruptFileError` (naming the file, and the
    line for text files) for truncated or malformed files.
    """
    p = Path(path)
    fmt = _format_of(p)
    check_readable(p, "marker file")  # absent / a directory / unreadable, said as such
    if fmt == ".c3d":
        seq = _read_c3d(p)
    elif fmt in (".trc", ".trc.gz"):
        seq = _read_trc(p)
    else:
        seq = _read_npz(p)
    return to_house_units(seq)
