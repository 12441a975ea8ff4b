"""``MarkerSequence`` (marker trajectories) and ``read_markers`` / ``write_npz``.

A marker sequence is ``positions`` of shape ``(T, M, 3)`` (frames, markers, xyz) with
NaN wherever a marker is missing (occluded, C3D negative residual, empty TRC cell, an
``NA`` table cell): missing is never 0. ``read_markers`` picks the format from the file
name (``.c3d``, ``.trc``, ``.trc.gz``, ``.npz``, and the tables ``.csv``, ``.tsv``,
``.txt``, each optionally ``.gz``); every reader raises `CorruptFileError` naming the
file and what is wrong. Every unit inferred, overridden or converted is said on the
console (``fxspace._progress.note``), and a marker set of implausible size for its
unit gets a warning naming the likely unit.
"""

from __future__ import annotations

import dataclasses
import io
import zipfile
from pathlib import Path

import numpy as np

from fxspace._progress import note
from fxspace._validate import check_readable, check_scalar, checked
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._c3d import _read_c3d
from fxspace.io._table import TABLE_EXTENSIONS, check_units_plausible, read_table
from fxspace.io._trc import _read_trc
from fxspace.io._types import (
    UNIT_SCALES,
    MarkerSequence,
    _check_seq,
    canonical_units,
    to_house_units,
)
from fxspace.runs import save_npz_atomic

__all__ = [
    "MarkerSequence",
    "read_markers",
    "write_npz",
    "SUPPORTED_EXTENSIONS",
    "UNIT_SCALES",
]

#: File name endings ``read_markers`` understands.
SUPPORTED_EXTENSIONS = (
    ".c3d", ".trc", ".trc.gz", ".npz",
    *TABLE_EXTENSIONS, *(e + ".gz" for e in TABLE_EXTENSIONS),
)  # fmt: skip

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
    for ext in TABLE_EXTENSIONS:
        if name.endswith(ext) or name.endswith(ext + ".gz"):
            return "table"
    raise FxspaceError(
        f"cannot read {path}: unknown marker file extension; supported: "
        f"{', '.join(SUPPORTED_EXTENSIONS)}"
    )


@checked
def read_markers(
    path: str | Path, *, units: str | None = None, rate: float | None = None
) -> MarkerSequence:
    """Read a marker file → `MarkerSequence`: ``.c3d``, ``.trc``, ``.trc.gz``, ``.npz``, or
    a marker table ``.csv`` / ``.tsv`` / ``.txt`` (each optionally ``.gz``).

    - **C3D** (via the ``c3d`` package): rate from the header, units from
      ``POINT:UNITS``, names from ``POINT:LABELS`` (stripped); points with a negative
      residual (invalid) are NaN, never 0. Analog channels are ignored.
    - **TRC** (OpenSim / Motion Analysis text, tab separated; ``.trc.gz`` gzipped): rate
      from ``DataRate``, units from ``Units``; empty cells are NaN.
    - **NPZ**: keys ``positions``, ``names``, ``rate``, ``units`` (see `write_npz`).
    - **Tables** (CSV/TSV exports; see ``fxspace.io._table``): separator ``,`` ``;`` or
      tab detected; ``NA``/``NaN``/empty/``-`` cells are NaN; marker columns
      ``NAME_x``/``NAME.X``/``NAME:X``/``NAME X``; the rate from a time column or
      ``rate``; other columns ignored and named in a note; units from ``units``, a
      bracketed unit in the header, or inferred from the data's extent (said).

    **Arguments:**

    - ``path``: the file.
    - ``units``: the length unit of the file's values (``"mm"``, ``"cm"``, ``"m"``,
      ``"in"``, ``"ft"`` or a spelling). For a table it declares them; for a file that
      declares its own it overrides that label (a metres file labelled ``"mm"``), said.
    - ``rate``: Hz, for a table without a time column (with one, or for another format,
      a rate that differs from the file's is refused).

    **Units**: a file in inches or feet is converted to millimetres (the house unit):
    ``seq.units == "mm"`` and ``seq.file_units`` records the file's unit (``"in"``);
    metric files keep their unit (``seq.to_units("mm")`` converts them). A marker set
    whose size is implausible for its unit (a frame under 30 mm or over 5 m across) gets
    a warning naming the likely unit and the fix.

    Positions are float64, except NPZ which keeps the stored dtype.

    **Raises:** ``FileNotFoundError`` when ``path`` does not exist; ``ValueError`` for an
    unknown extension or units; `CorruptFileError` (naming the file, and the
    line for text files) for truncated or malformed files.
    """
    p = Path(path)
    fmt = _format_of(p)
    check_readable(p, "marker file")  # absent / a directory / unreadable, said as such
    if units is not None:
        if not isinstance(units, str) or canonical_units(units) not in UNIT_SCALES:
            raise FxspaceError(
                f"units must be one of {sorted(UNIT_SCALES)} (or a spelling such as "
                f"'millimetres'), got {units!r}"
            )
        units = canonical_units(units)
    if rate is not None:
        rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    if fmt == "table":
        return _checked_units(to_house_units(read_table(p, units=units, rate=rate)), p)
    if fmt == ".c3d":
        seq = _read_c3d(p)
    elif fmt in (".trc", ".trc.gz"):
        seq = _read_trc(p)
    else:
        seq = _read_npz(p)
    if rate is not None and abs(rate - seq.rate) > 1e-9 * seq.rate:
        raise FxspaceError(
            f"{p}: rate={rate:g} Hz disagrees with the file's {seq.rate:g} Hz; drop the "
            "rate argument (a config: [data] rate = 0)"
        )
    if units is not None and units != seq.units:
        note(f"{p.name}: values read as {units!r} as asked (the file says {seq.units!r})")
        seq = dataclasses.replace(seq, units=units)
    return _checked_units(to_house_units(seq), p)


def _checked_units(seq: MarkerSequence, p: Path) -> MarkerSequence:
    if seq.file_units and seq.file_units != seq.units:
        note(f"{p.name}: converted from {seq.file_units!r} to {seq.units!r}")
    check_units_plausible(seq, p.name)
    return seq
