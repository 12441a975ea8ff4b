"""C3D marker files through the maintained ``c3d`` package (reader and writer).

Points whose residual word is negative are invalid (the C3D convention for a marker
not seen by the cameras): they become NaN, never 0. The ``c3d`` package reports a
truncated data section with a warning and stops early; here that is a
`CorruptFileError` naming the file and the frame counts.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._types import MarkerSequence, _check_seq
from fxspace.runs import write_bytes_atomic

__all__ = ["write_c3d"]

_C3D_MAGIC = 0x50  # second byte of every C3D file


def _read_c3d(path: Path) -> MarkerSequence:
    import c3d

    raw = path.read_bytes()
    if len(raw) < 512:
        raise CorruptFileError(f"{path}: {len(raw)} bytes, shorter than a C3D header (512 bytes)")
    if raw[1] != _C3D_MAGIC:
        raise CorruptFileError(
            f"{path}: not a C3D file (byte 2 is 0x{raw[1]:02x}, C3D files have 0x50)"
        )
    caught: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            reader = c3d.Reader(io.BytesIO(raw))
            n_points = int(reader.point_used)
            first, last = int(reader.first_frame), int(reader.last_frame)
            n_declared = last - first + 1
            if n_points <= 0:
                raise CorruptFileError(f"{path}: C3D file declares {n_points} points")
            if n_declared <= 0:
                raise CorruptFileError(
                    f"{path}: C3D header frame range {first}..{last} is empty or reversed"
                )
            frames = [pts[:, :4].copy() for _, pts, _ in reader.read_frames(copy=False)]
            rate = float(reader.header.frame_rate)
            if not np.isfinite(rate) or rate <= 0:
                rate = float(reader.point_rate)
            try:
                units = reader.get("POINT:UNITS").string_value.strip()
            except (AttributeError, KeyError):
                units = ""
            labels = [str(s).strip() for s in np.ravel(reader.point_labels)]
    except CorruptFileError:
        raise
    except Exception as e:  # the c3d package raises many kinds on garbage
        raise CorruptFileError(f"{path}: unreadable C3D file ({type(e).__name__}: {e})") from e
    eof = [w for w in caught if "end of file" in str(w.message).lower()]
    if len(frames) != n_declared or eof:
        raise CorruptFileError(
            f"{path}: truncated C3D data: the header declares {n_declared} frames "
            f"({first}..{last}) but only {len(frames)} could be read"
        )
    if not np.isfinite(rate) or rate <= 0:
        raise CorruptFileError(f"{path}: C3D frame rate {rate} is not > 0")
    if not units:
        raise CorruptFileError(f"{path}: C3D file has no POINT:UNITS (e.g. 'mm')")
    labels = labels[:n_points] + [""] * max(0, n_points - len(labels))
    names = tuple(lab if lab else f"marker{i + 1}" for i, lab in enumerate(labels))
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise CorruptFileError(f"{path}: POINT:LABELS has duplicated labels {dup}")

    data = np.stack(frames).astype(np.float64)  # (T, M, 4): x, y, z, residual
    pos = data[..., :3]
    pos[data[..., 3] < 0] = np.nan
    pos[~np.isfinite(pos).all(axis=-1)] = np.nan
    return MarkerSequence(pos, names, rate, units)


def write_c3d(path: str | Path, seq: MarkerSequence) -> Path:
    """Write ``seq`` as a C3D file (float32 points, no analog channels), atomically.

    Missing markers (NaN) are written as invalid points (residual −1), so
    `read_markers` reads them back as NaN; coordinates round-trip to
    float32 precision. Units go to ``POINT:UNITS``, the rate to the header and
    ``POINT:RATE``, the names to ``POINT:LABELS``.
    """
    import c3d

    _check_seq(seq)
    p = Path(path)
    if not p.name.lower().endswith(".c3d"):
        raise FxspaceError(f"path must end with .c3d, got {p.name!r}")
    if seq.n_frames == 0:
        raise FxspaceError("seq has no frames; a C3D file needs at least one")
    if seq.n_frames >= 65535:
        raise FxspaceError(
            f"seq has {seq.n_frames} frames; C3D headers hold at most 65534, write TRC/NPZ"
        )

    writer = c3d.Writer(point_rate=seq.rate, point_scale=-1.0, point_units=seq.units)
    writer.set_point_labels(list(seq.names))
    missing = seq.missing_mask()
    no_analog = np.zeros((0, 0), dtype=np.float32)
    frames = []
    for t in range(seq.n_frames):
        pts = np.zeros((seq.n_markers, 5), dtype=np.float32)
        pts[:, :3] = np.nan_to_num(seq.positions[t], nan=0.0)
        pts[missing[t], 3] = -1.0
        frames.append((pts, no_analog))
    writer.add_frames(frames)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No analog data found in file")
        writer.write(buf)
    return write_bytes_atomic(p, buf.getvalue())
