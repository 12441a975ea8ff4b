"""TRC marker files (OpenSim / Motion Analysis text format), plain or gzip-compressed.

Layout (tab separated)::

    PathFileType  4           (X/Y/Z)    take.trc
    DataRate      CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  ...
    60.00         60.00       902        41          mm     60.00         ...
    Frame#  Time  name1        name2 ...
                  X1  Y1  Z1   X2  Y2  Z2 ...
    (blank line)
    1  0.00000  x  y  z  x  y  z ...

An empty cell is a missing coordinate (NaN). The reader checks the declared frame and
marker counts against the data and raises `CorruptFileError`
with the file and the line number of the first problem — never the file's content (a
``.trc`` name on another file must not echo its first line into an error or a run's
``status.json``); marker names are quoted only once the header is a TRC header.
"""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path

import numpy as np

from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._types import MarkerSequence, _check_seq
from fxspace.runs import write_bytes_atomic

__all__ = ["write_trc"]

_REQUIRED = ("DataRate", "NumFrames", "NumMarkers", "Units")


def raw_bytes(path: Path) -> bytes:
    """The file's bytes, decompressed when its name ends in ``.gz`` (a torn or false
    archive: `CorruptFileError` naming the file)."""
    raw = path.read_bytes()
    if path.name.lower().endswith(".gz"):
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as e:
            raise CorruptFileError(f"{path}: not a readable gzip file ({e})") from e
    return raw


def _load_text(path: Path) -> str:
    raw = raw_bytes(path)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _read_trc(path: Path) -> MarkerSequence:
    lines = _load_text(path).splitlines()

    def fail(lineno: int, what: str) -> CorruptFileError:
        return CorruptFileError(f"{path}, line {lineno}: {what}")

    if len(lines) < 5:
        raise fail(len(lines), f"TRC header needs 5 lines, the file has only {len(lines)}")
    if not lines[0].startswith("PathFileType"):
        raise fail(1, "not a TRC file: the first line does not start with 'PathFileType'")

    keys = [k.strip() for k in lines[1].split("\t")]
    vals = [v.strip() for v in lines[2].split("\t")]
    header = dict(zip(keys, vals, strict=False))
    absent = [k for k in _REQUIRED if not header.get(k)]
    if absent:
        raise fail(3, f"TRC header lacks value(s) for {absent}")
    try:
        rate = float(header["DataRate"])
        n_frames = int(float(header["NumFrames"]))
        n_markers = int(float(header["NumMarkers"]))
    except ValueError:
        raise fail(3, "non-numeric DataRate/NumFrames/NumMarkers") from None
    if not np.isfinite(rate) or rate <= 0 or n_frames < 0 or n_markers <= 0:
        raise fail(3, f"invalid DataRate={rate}, NumFrames={n_frames} or NumMarkers={n_markers}")
    units = header["Units"]

    name_cells = lines[3].split("\t")
    if len(name_cells) < 2 or name_cells[0].strip() != "Frame#":
        raise fail(4, "expected the 'Frame#<TAB>Time<TAB>names...' row")
    names = [c.strip() for c in name_cells[2:] if c.strip()]
    if len(names) != n_markers:
        raise fail(4, f"NumMarkers declares {n_markers} markers but the name row has {len(names)}")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise fail(4, f"duplicated marker names in the name row: {dup[:5]}; rename them")
    axis_cells = [c.strip() for c in lines[4].split("\t")[2:] if c.strip()]
    if len(axis_cells) != 3 * n_markers:
        raise fail(
            5,
            f"the X1/Y1/Z1 row has {len(axis_cells)} labels, expected {3 * n_markers} "
            f"(3 per marker)",
        )

    n_cols = 2 + 3 * n_markers
    rows: list[list[str]] = []
    linenos: list[int] = []
    for i in range(5, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        cells = line.split("\t")
        if len(cells) < n_cols:
            raise fail(
                i + 1,
                f"data row has {len(cells)} columns, expected {n_cols} "
                f"(Frame#, Time and 3 x {n_markers} coordinates)",
            )
        if len(cells) > n_cols:
            if any(c.strip() for c in cells[n_cols:]):
                raise fail(i + 1, f"data row has {len(cells)} columns, expected {n_cols}")
            cells = cells[:n_cols]
        rows.append(cells[2:])
        linenos.append(i + 1)
    if len(rows) != n_frames:
        last = linenos[-1] if linenos else 5
        raise fail(
            last,
            f"NumFrames declares {n_frames} frames but the file has {len(rows)} data rows"
            + (" (truncated?)" if len(rows) < n_frames else ""),
        )

    cleaned = [[c if c.strip() else "nan" for c in r] for r in rows]
    try:
        data = np.array(cleaned, dtype=np.float64).reshape(n_frames, n_markers, 3)
    except ValueError:
        for r, lineno in zip(cleaned, linenos, strict=True):
            for j, c in enumerate(r):
                try:
                    float(c)
                except ValueError:
                    marker, axis = names[j // 3], "XYZ"[j % 3]
                    raise fail(lineno, f"non-numeric cell ({marker} {axis})") from None
        raise  # pragma: no cover - np.array failed but every cell parses
    if np.isinf(data).any():
        t, m, _ = np.argwhere(np.isinf(data))[0]
        raise fail(linenos[t], f"infinite coordinate for marker {names[m]}")
    try:
        return MarkerSequence(data, tuple(names), rate, units)
    except FxspaceError as e:  # pragma: no cover - every field checked above
        raise CorruptFileError(f"{path}: {e}") from e


def _fmt(v: float, precision: int | None) -> str:
    if v != v:  # NaN -> empty cell
        return ""
    return repr(v) if precision is None else f"{v:.{precision}f}"


def write_trc(path: str | Path, seq: MarkerSequence, *, precision: int | None = None) -> Path:
    """Write ``seq`` as a TRC file (``.trc``, or gzip-compressed ``.trc.gz``), atomically.

    Missing markers (NaN) are written as empty cells. With ``precision=None``
    (default) each coordinate is written with the shortest text that reads back to the
    same float64, so `read_markers` returns exactly the written
    values; ``precision=k`` writes ``k`` decimals (smaller files, rounding ≤ 0.5e-k).
    Marker names must not contain tabs or line breaks.
    """
    _check_seq(seq)
    p = Path(path)
    lname = p.name.lower()
    if not (lname.endswith(".trc") or lname.endswith(".trc.gz")):
        raise FxspaceError(f"path must end with .trc or .trc.gz, got {p.name!r}")
    if precision is not None and (int(precision) != precision or precision < 0):
        raise FxspaceError(f"precision must be None or an integer >= 0, got {precision!r}")
    bad = [n for n in seq.names if any(ch in n for ch in "\t\r\n")]
    if bad:
        raise FxspaceError(f"marker names {bad} contain tabs or line breaks; rename them first")

    T, M = seq.n_frames, seq.n_markers
    rate = repr(seq.rate)
    stem = p.name[: -len(".gz")] if lname.endswith(".gz") else p.name
    out = [
        f"PathFileType\t4\t(X/Y/Z)\t{stem}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
        "OrigDataStartFrame\tOrigNumFrames",
        f"{rate}\t{rate}\t{T}\t{M}\t{seq.units}\t{rate}\t1\t{T}",
        "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in seq.names),
        "\t\t" + "\t".join(f"X{k}\tY{k}\tZ{k}" for k in range(1, M + 1)),
        "",
    ]
    flat = seq.positions.astype(np.float64).reshape(T, 3 * M).tolist()
    for t, row in enumerate(flat):
        cells = "\t".join(_fmt(v, precision) for v in row)
        out.append(f"{t + 1}\t{t / seq.rate:.5f}\t{cells}")
    data = ("\n".join(out) + "\n").encode("utf-8")
    if lname.endswith(".gz"):
        data = gzip.compress(data, compresslevel=6, mtime=0)
    return write_bytes_atomic(p, data)
