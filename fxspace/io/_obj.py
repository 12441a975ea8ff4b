"""Wavefront OBJ, read fast: positions, triangles (polygons fanned), texture coordinates.

A blend-shape rig ships as one OBJ per shape (the ICT Face Model: 82 files, ~190 MB of
text): the reader finds the ``v`` / ``vt`` / ``f`` lines with one regular-expression pass
over the bytes and converts the numbers in one numpy call, so a 26 719-vertex shape
reads in a few tens of milliseconds (a line-by-line Python loop takes ~0.5 s). Gzip
files (``.obj.gz``) are read as they are.

Example:

```python
m = fx.io.read_obj_mesh("neutral.obj.gz")   # .vertices (N, 3), .faces (F, 3), .uvs, .face_uvs
v = fx.io.read_obj_vertices("jawOpen.obj.gz")  # positions only (N, 3)
```
"""

from __future__ import annotations

import gzip
import re
import stat
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fxspace._validate import checked
from fxspace.errors import CorruptFileError, FxspaceError

__all__ = ["ObjMesh", "read_obj_mesh", "read_obj_vertices"]

_V = re.compile(rb"^v[ \t]+([^\n\r#]*)", re.M)
_VT = re.compile(rb"^vt[ \t]+([^\n\r#]*)", re.M)
_F = re.compile(rb"^f[ \t]+([^\n\r#]*)", re.M)


class ObjMesh(NamedTuple):
    """A static OBJ mesh: ``vertices`` ``(N, 3)`` float64, ``faces`` ``(F, 3)`` int64
    (polygons fanned into triangles), ``uvs`` ``(U, 2)`` and ``face_uvs`` ``(F, 3)``
    (indices into ``uvs`` per triangle corner; ``None`` where the file has none)."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    face_uvs: np.ndarray | None


def _bytes(path: str | Path) -> tuple[Path, bytes]:
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise FxspaceError(f"{p}: no such file") from None
    if not stat.S_ISREG(st.st_mode):
        raise FxspaceError(f"{p}: not a regular file (a folder, pipe or device); pass an OBJ file")
    data = p.read_bytes()
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as e:
            raise CorruptFileError(
                f"{p}: damaged gzip stream ({type(e).__name__}); restore the file from its "
                "source"
            ) from None
    return p, data


def _line_of(regex: re.Pattern, data: bytes, k: int) -> int:
    """The file line number of the `k`-th match of `regex` (for error messages)."""
    for i, m in enumerate(regex.finditer(data)):
        if i == k:
            return data.count(b"\n", 0, m.start()) + 1
    return 0


def _numbers(regex: re.Pattern, data: bytes, width: int, p: Path, what: str) -> np.ndarray:
    """The first `width` numbers of each line `regex` finds, one numpy conversion for the
    whole file; a malformed line raises `CorruptFileError` with its line number."""
    lines = regex.findall(data)
    if not lines:
        return np.zeros((0, width))
    counts = np.fromiter((len(ln.split()) for ln in lines), int, len(lines))
    try:
        if np.all(counts == width):
            return np.array(b" ".join(lines).split()).astype(np.float64).reshape(-1, width)
        if np.all(counts >= width):
            return np.array([ln.split()[:width] for ln in lines]).astype(np.float64)
    except ValueError:
        pass
    for k, ln in enumerate(lines):  # find the culprit
        try:
            if len([float(x) for x in ln.split()[:width]]) < width:
                raise ValueError(f"fewer than {width} numbers")
        except ValueError as e:
            n = _line_of(regex, data, k)
            why = "too few numbers" if "fewer" in str(e) else "not a number"
            raise CorruptFileError(
                f"{p}:{n}: malformed {what} line ({why}; expected {width} numbers)"
            ) from None
    raise CorruptFileError(f"{p}: malformed {what} lines")  # pragma: no cover


@checked
def read_obj_vertices(path: str | Path) -> np.ndarray:
    """The ``(N, 3)`` vertex positions of an OBJ file (``.obj`` or ``.obj.gz``)."""
    p, data = _bytes(path)
    v = _numbers(_V, data, 3, p, "vertex")
    if len(v) == 0:
        raise CorruptFileError(f"{p}: no vertices ('v x y z' lines)")
    return v


def _corners(tokens: list[bytes], n: int, p: Path, slot: int) -> list[int]:
    out = []
    for t in tokens:
        parts = t.split(b"/")
        if len(parts) <= slot or not parts[slot]:
            return []
        i = int(parts[slot])
        out.append(i - 1 if i > 0 else n + i)
    return out


def _fast_faces(lines: list[bytes], n: int) -> np.ndarray | None:
    """The position indices of face lines that all have the same corner count, fanned,
    in a few numpy calls (``None`` when the counts differ or an index is not an
    integer: the line-by-line parse then finds the culprit)."""
    if not lines:
        return np.zeros((0, 3), np.int64)
    counts = {len(ln.split()) for ln in lines}
    if len(counts) != 1 or min(counts) < 3:
        return None
    (c,) = counts
    try:
        idx = np.array(re.sub(rb"/[^\s]*", b"", b" ".join(lines)).split()).astype(np.int64)
    except ValueError:
        return None
    idx = idx.reshape(-1, c)
    idx = np.where(idx > 0, idx - 1, n + idx)
    fan = [np.stack([idx[:, 0], idx[:, k], idx[:, k + 1]], 1) for k in range(1, c - 1)]
    return np.stack(fan, 1).reshape(-1, 3)


@checked
def read_obj_mesh(path: str | Path, *, uvs: bool = True) -> ObjMesh:
    """Positions, triangles and texture coordinates of an OBJ file (``.obj`` or
    ``.obj.gz``); polygons are fanned into triangles (a quad ``a b c d`` gives ``a b c``
    and ``a c d``), each triangle keeps its corners' UV indices. ``uvs=False`` skips the
    texture coordinates (``uvs`` and ``face_uvs`` are ``None``) and reads the triangles
    in a few numpy calls (a rig's shapes: their topology checked against the
    neutral's). A malformed file raises `CorruptFileError` naming it."""
    p, data = _bytes(path)
    v = _numbers(_V, data, 3, p, "vertex")
    if len(v) == 0:
        raise CorruptFileError(f"{p}: no vertices ('v x y z' lines)")
    if not uvs:
        F = _fast_faces(_F.findall(data), len(v))
        if F is not None:
            if len(F) and (F.min() < 0 or F.max() >= len(v)):
                raise CorruptFileError(f"{p}: a face refers to a missing vertex")
            return ObjMesh(v, F, None, None)
    uvs = _numbers(_VT, data, 2, p, "texture") if uvs else np.zeros((0, 2))
    uvs = uvs if len(uvs) else None
    nuv = 0 if uvs is None else len(uvs)
    faces, fuv = [], []
    has_uv = uvs is not None
    try:
        for line in _F.findall(data):
            tok = line.split()
            idx = _corners(tok, len(v), p, 0)
            if len(idx) < 3:
                n = data.count(b"\n", 0, data.find(line)) + 1
                raise CorruptFileError(f"{p}:{n}: a face with fewer than 3 corners")
            tri = [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
            faces += tri
            if has_uv:
                ti = _corners(tok, nuv, p, 1)
                if len(ti) != len(idx):
                    has_uv = False
                else:
                    fuv += [(ti[0], ti[k], ti[k + 1]) for k in range(1, len(ti) - 1)]
    except ValueError:
        raise CorruptFileError(f"{p}: malformed face line (non-integer index)") from None
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(F) and (F.min() < 0 or F.max() >= len(v)):
        raise CorruptFileError(f"{p}: a face refers to a missing vertex")
    FU = np.asarray(fuv, np.int64).reshape(-1, 3) if has_uv else None
    if FU is not None and len(FU) and (FU.min() < 0 or FU.max() >= nuv):
        raise CorruptFileError(f"{p}: a face refers to a missing texture coordinate")
    return ObjMesh(v, F, uvs if has_uv else None, FU)
