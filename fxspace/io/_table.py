"""Marker tables (CSV / TSV text exports).

A lab's marker export is often a text table, one row per frame::

    Frame;Time;lip_l_x;lip_l_y;lip_l_z;brow.X;brow.Y;brow.Z;label
    1;0.000;12.1;-3.4;51.0;NA;NA;NA;neutral
    2;0.017;12.2;-3.3;51.1;40.2;18.0;60.1;neutral

`read_table` reads it into a `MarkerSequence`:

- **separator**: ``,``, ``;`` or tab, detected from the header (the one that splits the
  header and the first rows into the same number of cells); ``sep=`` forces one. With
  ``;`` or tab, decimal commas (``12,1``) are read as decimal points.
- **missing values**: empty cells and ``NA``, ``N/A``, ``NaN``, ``null``, ``None``,
  ``-`` (any case) are NaN — never 0.
- **marker columns**: three columns ``NAME<sep>X``, ``NAME<sep>Y``, ``NAME<sep>Z`` with
  ``<sep>`` one of ``_`` ``.`` ``:`` ``-`` or a space, and X/Y/Z in either case
  (``lip_x``, ``lip.X``, ``lip:X``, ``lip X``); a unit in brackets after a column name
  (``lip_x (mm)``, ``lip_x [m]``) declares the units.
- **frame or time column**: ``Frame``/``Frame#``/``Index``/``Sample`` (gaps in the
  numbering become rows of NaN, said) and ``Time``/``Time (s)``/``t``/``Time_ms``: the
  rate comes from the time column, or from ``rate=``.
- **other columns** (a label, a sub-frame, a marker with only two axes) are ignored and
  named in a note.
- **two-row headers** (a Vicon Nexus "Trajectories" CSV: a preamble with the rate, a row
  of marker names ``Subject:LFHD`` over ``X,Y,Z`` columns, a units row) are read too; a
  subject prefix shared by every marker is dropped.
- **units**: ``units=`` declares them; else a bracketed unit in the header; else they are
  inferred from the data's extent (`infer_units`) and the inference is said.

Notes go through ``fxspace._progress.note`` (a console line and an ``fxspace`` log
record). The unit checks every marker reader shares (`marker_extent`, `infer_units`,
`check_units_plausible`) live in ``fxspace.io._marker_units`` and are re-exported here.
"""

from __future__ import annotations

import gzip
import re
from pathlib import Path

import numpy as np

from fxspace._progress import note
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._marker_units import check_units_plausible, infer_units, marker_extent
from fxspace.io._trc import raw_bytes
from fxspace.io._types import MarkerSequence, _check_seq, canonical_units

__all__ = [
    "TABLE_EXTENSIONS",
    "MISSING_TOKENS",
    "read_table",
    "write_table",
    "marker_extent",
    "infer_units",
    "check_units_plausible",
]

#: File name endings read as marker tables (each also gzipped: ``.csv.gz``).
TABLE_EXTENSIONS = (".csv", ".tsv", ".txt")

#: Cells read as a missing value (NaN), compared case-insensitively after stripping.
MISSING_TOKENS = ("", "na", "n/a", "nan", "null", "none", "-")

_SEPS = {"\t": "tab", ";": "';'", ",": "','"}
_AXIS = re.compile(r"^(?P<name>.+?)[ _.:\-]+(?P<axis>[xyzXYZ])$")
_UNIT = re.compile(r"^(?P<col>.*?)\s*[\(\[](?P<unit>[^\)\]]+)[\)\]]\s*$")
_FRAME = {"frame", "frame#", "frames", "frame_number", "frame number", "frame no", "index",
          "sample", "frame_no", "frameno"}  # fmt: skip
_TIME_S = {"time", "t", "time_s", "time (s)", "time [s]", "seconds", "sec", "timestamp"}
_TIME_MS = {"time_ms", "time (ms)", "time [ms]", "ms", "milliseconds"}


# -- text -----------------------------------------------------------------------------------
def _load_text(path: Path) -> str:
    raw = raw_bytes(path)
    if b"\x00" in raw[:4096]:
        raise CorruptFileError(f"{path}: binary data, not a text table")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _detect_sep(path: Path, rows: list[tuple[int, str]], sep: str | None) -> str:
    if sep is not None:
        if sep not in _SEPS:
            raise FxspaceError(f"sep must be one of ',', ';' or '\\t' (tab), got {sep!r}")
        return sep
    head = [ln for _, ln in rows[:20]]
    best, best_score = None, 0
    for cand in ("\t", ";", ","):  # the one that splits most rows into the same count
        counts = [ln.count(cand) for ln in head]
        many = [c for c in counts if c >= 2]
        if not many:
            continue
        mode = max(set(many), key=many.count)
        score = counts.count(mode)
        if score > best_score:
            best, best_score = cand, score
    if best is None:
        raise CorruptFileError(
            f"{path}, line {rows[0][0]}: no ',', ';' or tab separates the header into columns "
            "(a marker table needs NAME_x, NAME_y, NAME_z columns)"
        )
    return best


def _two_row_header(rows: list[tuple[int, str]], s: str):
    """A header of two rows — marker names over their X/Y/Z columns (a Vicon Nexus
    "Trajectories" export: a preamble, ``,,Sub:LFHD,,,Sub:RFHD``, ``Frame,Sub Frame,X,Y,Z``,
    an optional units row): ``(header, first data row, rate, unit)`` or ``None``."""
    for k in range(min(len(rows) - 1, 12)):
        names = [c.strip().strip('"') for c in rows[k][1].split(s)]
        axes = [c.strip().strip('"').upper() for c in rows[k + 1][1].split(s)]
        starts = [i for i in range(len(axes) - 2) if axes[i : i + 3] == ["X", "Y", "Z"]
                  and i < len(names) and names[i]]  # fmt: skip
        if not starts:
            continue
        prefix = {n.split(":", 1)[0] for n in (names[i] for i in starts) if ":" in n}
        strip = len(prefix) == 1 and all(":" in names[i] for i in starts)
        header = [c for c in (x.strip().strip('"') for x in rows[k + 1][1].split(s))]
        for i in starts:
            name = names[i].split(":", 1)[1] if strip else names[i]
            for j, a in enumerate("xyz"):
                header[i + j] = f"{name}_{a}"
        first, unit = k + 2, None
        if first < len(rows):
            cells = [c.strip().strip('"') for c in rows[first][1].split(s)]
            units = {cells[i] for i in starts if i < len(cells) and cells[i]}
            if units and all(re.fullmatch(r"[A-Za-z]+", u) for u in units):
                unit = units.pop() if len(units) == 1 else None
                first += 1
        rate = None
        for _, ln in rows[:k]:
            cells = [c.strip() for c in ln.split(s) if c.strip()]
            if len(cells) == 1:
                try:
                    rate = float(cells[0])
                except ValueError:
                    continue
        return header, first, rate, unit
    return None


def _classify(header: list[str]):
    """Columns → (markers {name: [ix, iy, iz]} in order, frame col, (time col, scale),
    unit from brackets, other column names)."""
    groups: dict[str, dict[str, int]] = {}
    frame_col, time_col, units = None, None, set()
    other: list[str] = []
    for i, raw in enumerate(header):
        cell = raw.strip().strip('"').strip()
        m = _UNIT.match(cell)
        base, unit = (m["col"], m["unit"].strip()) if m else (cell, None)
        low = cell.lower()
        if low in _FRAME and frame_col is None:
            frame_col = i
            continue
        if (low in _TIME_S or low in _TIME_MS) and time_col is None:
            time_col = (i, 1e-3 if low in _TIME_MS else 1.0)
            continue
        a = _AXIS.match(base)
        if a and a["name"].strip():
            g = groups.setdefault(a["name"].strip(), {})
            ax = a["axis"].lower()
            if ax in g:  # a duplicated axis: keep the first, name the second
                other.append(cell)
                continue
            g[ax] = i
            if unit:
                units.add(unit)
            continue
        other.append(cell or f"(column {i + 1}, no name)")
    markers = {}
    for name, g in groups.items():
        if set(g) == {"x", "y", "z"}:
            markers[name] = [g["x"], g["y"], g["z"]]
        else:
            other += [header[i].strip() for i in g.values()]
    return markers, frame_col, time_col, units, other


def _numbers(path, cells: list[list[str]], cols: list[int], lines: list[int], comma: bool,
             header: list[str]) -> np.ndarray:  # fmt: skip
    """The columns ``cols`` of every row as float64, missing tokens NaN."""
    out = np.empty((len(cells), len(cols)), np.float64)
    for r, row in enumerate(cells):
        for k, c in enumerate(cols):
            v = row[c].strip().strip('"').strip()
            if v.lower() in MISSING_TOKENS:
                out[r, k] = np.nan
                continue
            if comma:
                v = v.replace(",", ".")
            try:
                out[r, k] = float(v)
            except ValueError:
                raise CorruptFileError(
                    f"{path}, line {lines[r]}: column {header[c].strip()!r} holds a value that "
                    f"is not a number ({v[:20]!r}); missing values may be empty, NA, NaN or -"
                ) from None
    if np.isinf(out).any():
        r = int(np.flatnonzero(np.isinf(out).any(axis=1))[0])
        raise CorruptFileError(f"{path}, line {lines[r]}: an infinite value; mark missing as NA")
    return out


def read_table(
    path: str | Path,
    *,
    units: str | None = None,
    rate: float | None = None,
    sep: str | None = None,
) -> MarkerSequence:
    """Read a marker table (``.csv``, ``.tsv``, ``.txt``, each optionally ``.gz``); see the
    module docstring for the layout. ``units`` (a ``UNIT_SCALES`` key or spelling)
    declares the units, ``rate`` (Hz) the frame rate when the table has no time column
    (with one, they must agree within 1 %), ``sep`` forces the separator.

    **Raises:** `CorruptFileError` naming the file and line (no header, no marker columns,
    a row of the wrong length, a cell that is not a number, an uneven or decreasing time
    column); `FxspaceError` when the rate is neither in the file nor given.
    """
    path = Path(path)
    text = _load_text(path)
    rows = [(n + 1, ln) for n, ln in enumerate(text.splitlines())
            if ln.strip() and not ln.lstrip().startswith("#")]  # fmt: skip
    if not rows:
        raise CorruptFileError(f"{path}: empty marker table (no header row)")
    s = _detect_sep(path, rows, sep)
    header = rows[0][1].split(s)
    markers, frame_col, time_col, hdr_units, other = _classify(header)
    said = []
    two = None if markers else _two_row_header(rows, s)
    if two is not None:
        header, first, file_rate, file_unit = two
        markers, frame_col, time_col, hdr_units, other = _classify(header)
        rows = [rows[first - 1], *rows[first:]]  # a stand-in header row, then the data
        said.append("two-row header (names over X/Y/Z)")
        if file_unit:
            hdr_units = {file_unit}
        if rate is None and file_rate is not None and time_col is None:
            rate = file_rate
            said.append(f"rate {rate:g} Hz from the preamble")
    if not markers:
        raise CorruptFileError(
            f"{path}, line {rows[0][0]}: no marker columns: a marker needs three columns "
            "NAME_x, NAME_y, NAME_z (or NAME.X, NAME:X, 'NAME X'); "
            f"separator {_SEPS[s]}, {len(header)} columns"
        )
    body = rows[1:]
    if not body:
        raise CorruptFileError(f"{path}: the table has a header but no rows")
    cells, lines = _split_rows(path, body, s, header)
    # decimal commas: only where ',' is not the separator and cells hold no '.'
    comma = s != "," and any("," in c[i] for c in cells[:50] for ix in markers.values()
                                for i in ix)  # fmt: skip
    names = list(markers)
    cols = [i for ix in markers.values() for i in ix]
    xyz = _numbers(path, cells, cols, lines, comma, header).reshape(len(cells), len(names), 3)
    if comma:
        said.append("decimal commas read as points")

    xyz, fr = _fill_frame_gaps(path, cells, frame_col, lines, header, xyz, said)
    rate = _table_rate(path, cells, time_col, frame_col, fr, lines, comma, header, len(xyz),
                       rate, said)  # fmt: skip

    if other:
        shown = ", ".join(repr(o) for o in other[:8]) + (" …" if len(other) > 8 else "")
        said.append(f"{len(other)} non-marker column(s) ignored: {shown}")

    u = _table_units(path, units, hdr_units, xyz, said)
    sep_name = _SEPS[s]
    note(f"{path.name}: {len(names)} markers × {len(xyz)} frames, separator {sep_name}"
         + "".join(f"; {x}" for x in said))  # fmt: skip
    try:
        return MarkerSequence(xyz, tuple(names), float(rate), u)
    except FxspaceError as e:
        raise CorruptFileError(f"{path}: {e}") from None


def _split_rows(path, body, s: str, header: list[str]) -> tuple[list[list[str]], list[int]]:
    """``(cells, line numbers)`` of the data rows split at ``s`` (a trailing separator
    dropped); a row whose length differs from the header's is refused."""
    cells, lines = [], []
    for n, ln in body:
        c = ln.split(s)
        if len(c) > len(header) and all(not x.strip() for x in c[len(header) :]):
            c = c[: len(header)]  # a trailing separator
        if len(c) != len(header):
            raise CorruptFileError(
                f"{path}, line {n}: {len(c)} cells, the header has {len(header)} "
                f"(separator {_SEPS[s]}; a truncated or ragged row)"
            )
        cells.append(c)
        lines.append(n)
    return cells, lines


def _fill_frame_gaps(path, cells, frame_col, lines, header, xyz: np.ndarray, said: list):
    """``(xyz, frame numbers)``: with a frame column, checked to be increasing integers,
    gaps in it become NaN rows (``None`` for the frame numbers without one)."""
    if frame_col is None:
        return xyz, None
    fr = _numbers(path, cells, [frame_col], lines, False, header)[:, 0]
    if np.isnan(fr).any() or np.any(fr != np.round(fr)):
        bad = int(np.flatnonzero(np.isnan(fr) | (fr != np.round(fr)))[0])
        raise CorruptFileError(f"{path}, line {lines[bad]}: the frame number is not an integer")
    d = np.diff(fr)
    if (d <= 0).any():
        bad = int(np.flatnonzero(d <= 0)[0]) + 1
        raise CorruptFileError(
            f"{path}, line {lines[bad]}: frame numbers must increase (frame {fr[bad]:g} "
            f"follows {fr[bad - 1]:g})"
        )
    if (d > 1).any():
        full = np.full((int(fr[-1] - fr[0]) + 1, xyz.shape[1], 3), np.nan)
        full[(fr - fr[0]).astype(int)] = xyz
        said.append(f"{len(full) - len(xyz)} frame(s) absent from the frame numbering "
                    "inserted as missing (NaN)")  # fmt: skip
        xyz = full
    return xyz, fr


def _table_rate(path, cells, time_col, frame_col, fr, lines, comma, header, n_frames: int,
                rate, said: list) -> float:
    """The frame rate (Hz): from the time column (checked against a given ``rate``) or
    given; refused when neither."""
    if time_col is not None:
        i, sc = time_col
        t = _numbers(path, cells, [i], lines, comma, header)[:, 0] * sc
        if frame_col is not None and len(t) < n_frames:  # rows were inserted: per row
            t_rate = _rate_from_time(path, t, lines, steps=np.diff(fr))
        else:
            t_rate = _rate_from_time(path, t, lines)
        if rate is not None and t_rate is not None and abs(t_rate - rate) > 0.01 * rate:
            raise FxspaceError(
                f"{path}: rate={rate:g} Hz disagrees with the time column ({t_rate:.6g} Hz); "
                "drop the rate argument (config: [data] rate = 0) or fix the time column"
            )
        if rate is None:
            if t_rate is None:
                raise FxspaceError(f"{path}: one row only, so no rate in the time column; "
                                   "pass rate=… Hz (config: [data] rate)")  # fmt: skip
            rate = t_rate
            said.append(f"rate {rate:.6g} Hz from the time column {header[i].strip()!r}")
    elif rate is None:
        raise FxspaceError(
            f"{path}: the table has no time column, so its frame rate is unknown; pass "
            "rate=… Hz to read_markers (a config: [data] rate = 120.0)"
        )
    return rate


def _table_units(path, units, hdr_units: set, xyz: np.ndarray, said: list) -> str:
    """The table's units: given, declared by the header, or inferred from the data."""
    if units is not None:
        u = canonical_units(units)
    elif len(hdr_units) == 1:
        u = canonical_units(hdr_units.pop())
        said.append(f"units {u!r} from the header")
    elif len(hdr_units) > 1:
        raise CorruptFileError(
            f"{path}: the header declares several units {sorted(hdr_units)}; "
            "pass units=… for the whole table"
        )
    else:
        u, why = infer_units(xyz)
        said.append(f"units inferred as {u!r} from the data's extent ({why}); "
                    f"declare them with units=… (a config: [data] units) if not")  # fmt: skip
    return u


def _rate_from_time(path, t: np.ndarray, lines, steps: np.ndarray | None = None):
    """Hz from a time column (seconds), checked even: ``None`` for a single row."""
    if len(t) < 2:
        return None
    if np.isnan(t).any():
        bad = int(np.flatnonzero(np.isnan(t))[0])
        raise CorruptFileError(f"{path}, line {lines[bad]}: the time column has a missing value")
    dt = np.diff(t)
    if steps is not None:
        dt = dt / steps
    if (dt <= 0).any():
        bad = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise CorruptFileError(f"{path}, line {lines[bad]}: the time column must increase")
    med = float(np.median(dt))
    off = np.abs(dt - med) > 0.01 * med + 1e-9
    if off.any():
        bad = int(np.flatnonzero(off)[0]) + 1
        raise CorruptFileError(
            f"{path}, line {lines[bad]}: the time column is not evenly spaced (step "
            f"{dt[bad - 1]:.6g} s, the median step is {med:.6g} s); rows may be missing — "
            "add a frame column, or fix the export"
        )
    n_steps = float(np.sum(steps)) if steps is not None else float(len(t) - 1)
    hz = n_steps / float(t[-1] - t[0])  # the whole span: rounded times average out
    return float(round(hz)) if abs(hz - round(hz)) <= 1e-4 * hz else hz


def write_table(
    path: str | Path,
    seq: MarkerSequence,
    *,
    sep: str = ",",
    missing: str = "",
    style: str = "{name}_{axis}",
    columns: dict[str, list] | None = None,
    decimals: int = 6,
) -> Path:
    """Write ``seq`` as a marker table that `read_table` reads back (atomic; ``.gz``
    compressed): a ``Frame`` and a ``Time`` column, then ``style`` columns per marker
    (``"{name}_{axis}"`` → ``lip_x``; ``"{name}.{AXIS}"`` → ``lip.X``), then ``columns``
    (extra non-marker columns, one value per frame, e.g. a label). Missing values are
    written as ``missing`` (``""``, ``"NA"``, ``"NaN"``…); ``sep`` is ``,``, ``;`` or tab.
    The units are not written: read the table back with ``units=seq.units``.
    """
    from fxspace.runs import write_bytes_atomic

    _check_seq(seq)
    if sep not in _SEPS:
        raise FxspaceError(f"sep must be one of ',', ';' or '\\t' (tab), got {sep!r}")
    if missing.strip().lower() not in MISSING_TOKENS:
        raise FxspaceError(f"missing must be one of {list(MISSING_TOKENS)}, got {missing!r}")
    extra = dict(columns or {})
    for k, v in extra.items():
        if len(v) != seq.n_frames:
            raise FxspaceError(f"columns[{k!r}] has {len(v)} values; seq has {seq.n_frames} frames")
    head = ["Frame", "Time"] + [
        style.format(name=n, axis=a, AXIS=a.upper()) for n in seq.names for a in "xyz"
    ] + list(extra)  # fmt: skip
    rows = [sep.join(head)]
    pos = np.asarray(seq.positions, np.float64).reshape(seq.n_frames, -1)
    for t in range(seq.n_frames):
        cells = [str(t + 1), f"{t / seq.rate:.9g}"]
        cells += [missing if np.isnan(v) else f"{v:.{decimals}f}" for v in pos[t]]
        cells += [str(extra[k][t]) for k in extra]
        rows.append(sep.join(cells))
    data = ("\n".join(rows) + "\n").encode("utf-8")
    p = Path(path)
    if p.name.lower().endswith(".gz"):
        data = gzip.compress(data, mtime=0)
    return write_bytes_atomic(p, data)
