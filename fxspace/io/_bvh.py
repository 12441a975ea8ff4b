"""BVH (Biovision hierarchy) reader and writer that keep each joint's channel order.

Angles are degrees in the file; a joint whose channels list rotations in the order
``Zrotation Yrotation Xrotation`` has local rotation ``R = R_Z(z) @ R_Y(y) @ R_X(x)``
(the order of the channels, read left to right, is the order of the matrix product).
Lengths are multiplied by ``scale`` on reading (file units → metres) and divided by it
on writing, so ``write_bvh(p, read_bvh(p, scale=s), scale=s)`` reproduces the file's units.
BVH declares no unit: ``units=`` names it (``"cm"`` for the Bandai Namco files) or
``units="auto"`` infers it from the skeleton's size; either is said on the console, and a
skeleton of implausible size in metres (the default) gets a warning naming the likely unit.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fxspace._progress import note
from fxspace._validate import check_readable, check_scalar, checked
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.motion import Motion
from fxspace.rotations import euler_to_quat, quat_rotate, quat_to_euler

__all__ = ["read_bvh", "write_bvh"]

_ROT = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


def _open_text(path: Path) -> str:
    raw = check_readable(path, "file").read_bytes()  # absent / directory / permission
    if path.suffix == ".gz" or raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError) as e:
            raise CorruptFileError(f"{path}: not a valid gzip file ({e})") from e
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


class _Tokens:
    def __init__(self, lines: list[str], path: Path):
        self.toks = [(t, n + 1) for n, line in enumerate(lines) for t in line.split()]
        self.i = 0
        self.path = path

    def error(self, msg: str, line: int | None = None) -> CorruptFileError:
        if line is None:
            line = self.toks[min(self.i, len(self.toks) - 1)][1] if self.toks else 1
        return CorruptFileError(f"{self.path}, line {line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.i >= len(self.toks):
            raise self.error(f"unexpected end of file, expected {what}")
        t = self.toks[self.i]
        self.i += 1
        return t

    def expect(self, word: str) -> int:
        t, n = self.next(repr(word))
        if t != word:
            raise self.error(f"expected {word!r}, found {t!r}", n)
        return n

    def number(self, what: str) -> float:
        t, n = self.next(what)
        try:
            return float(t)
        except ValueError:
            raise self.error(f"expected a number for {what}, found {t!r}", n) from None


_UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
_UNIT_SPELLING = {"meter": "m", "meters": "m", "metre": "m", "metres": "m",
                  "centimeter": "cm", "centimeters": "cm", "centimetre": "cm",
                  "centimetres": "cm", "millimeter": "mm", "millimeters": "mm",
                  "millimetre": "mm", "millimetres": "mm", "inch": "in", "inches": "in",
                  "foot": "ft", "feet": "ft"}  # fmt: skip


def _rest_extent(parents, offsets) -> float:
    """The diagonal of the box holding the rest-pose joints (file units)."""
    pos = np.zeros((len(parents), 3))
    for j, p in enumerate(parents):
        pos[j] = np.asarray(offsets[j], float) + (pos[p] if p >= 0 else 0.0)
    return float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))


def _unit_for_extent(e: float) -> str | None:
    """The unit that makes a skeleton ``e`` file units across a person (1–3 m diagonal,
    within a factor 1.2), ``None`` when no unit does."""
    best, best_d = None, np.inf
    for u, m in _UNITS_M.items():
        v = e * m
        d = 0.0 if 1.0 <= v <= 3.0 else min(abs(np.log(v / 1.0)), abs(np.log(v / 3.0)))
        if d < best_d - 1e-12:
            best, best_d = u, d
    return best if best_d <= np.log(1.2) else None


@checked
def read_bvh(path: str | Path, scale: float = 1.0, *, units: str | None = None) -> Motion:
    """Read a ``.bvh`` (or ``.bvh.gz``) file into a `Motion`.

    **Arguments:**

    - ``path``: the file.
    - ``scale``: metres per file length unit (CMU's BVH conversion uses the ASF unit,
      ``0.0254 / 0.45`` m).
    - ``units``: the file's length unit instead of ``scale``: ``"m"``, ``"cm"`` (the
      Bandai Namco files), ``"mm"``, ``"in"``, ``"ft"``, or ``"auto"`` (inferred from the
      rest skeleton's size, for a human-sized figure); said on the console. With neither,
      lengths are metres, and a skeleton under 0.3 m or over 5 m across gets a warning
      naming the likely unit.

    **Returns:** a ``Motion``; end sites become joints named ``<parent>_end``.

    Position channels may sit on any joint (game-pipeline BVH such as the Bandai Namco
    dataset, 6 channels per joint): their values replace the joint's OFFSET. Constant ones
    become the offset; a varying one on the root's only child (the usual ``Hips`` under a
    static ``Root``) is folded into the root translation, so every joint below the root
    keeps its world position (`fxspace.motion.drop_root` then removes the static root).
    Other varying translations (stretching bones) raise ``CorruptFileError``.

    Raises ``CorruptFileError`` naming the line of the first malformed token (a ``Frame
    Time`` that is not a finite positive number included), and `FxspaceError` for a
    ``scale`` that is not a finite positive number, an unknown ``units``, or both given.
    """
    scale = check_scalar(scale, "scale", low=0.0, low_open=True)
    units = _check_units(scale, units)
    path = Path(path)
    lines = _open_text(path).splitlines()
    try:
        mline = next(i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION")
    except StopIteration:
        raise CorruptFileError(f"{path}: no MOTION section (is this a BVH file?)") from None
    tk = _Tokens(lines[:mline], path)
    tk.expect("HIERARCHY")
    names, parents, offsets, channels = _parse_hierarchy(tk)
    extent = _rest_extent(parents, offsets)
    scale = _scale_for_units(path, extent, units, scale)
    n_ch = sum(len(c) for c in channels)
    data, dt = _read_frames(path, lines, mline, n_ch)
    quats, root, local = _decode_channels(data, channels, parents, offsets)
    offsets_np = np.asarray(offsets, dtype=np.float64)
    if local:
        _fold_joint_translations(path, names, parents, offsets_np, root, quats, local)
    return Motion(
        names=tuple(names),
        parents=tuple(parents),
        offsets=jnp.asarray(offsets_np * scale),
        root_translation=jnp.asarray(root * scale),
        rotations=jnp.asarray(quats),
        rate=float(1.0 / dt),
        channels=tuple(channels),
    )


def _check_units(scale: float, units: str | None) -> str | None:
    """``units`` in its canonical spelling (``None`` stays ``None``); refuses an unknown
    unit and ``units`` given together with a ``scale`` other than 1."""
    if units is None:
        return None
    u = units.strip().lower() if isinstance(units, str) else units
    u = _UNIT_SPELLING.get(u, u)
    if u != "auto" and u not in _UNITS_M:
        raise FxspaceError(
            f"units must be one of {sorted(_UNITS_M)} or 'auto', got {units!r}"
        )
    if scale != 1.0:
        raise FxspaceError(
            f"give scale (metres per file unit) or units, not both (scale={scale:g}, "
            f"units={units!r})"
        )
    return u


def _parse_hierarchy(tk: _Tokens):
    """``(names, parents, offsets, channels)`` of the HIERARCHY section after its
    keyword, end sites as joints named ``<parent>_end``; errors name the line."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []

    def joint(parent: int, is_end: bool, name: str) -> None:
        idx = len(names)
        names.append(name)
        parents.append(parent)
        tk.expect("{")
        tk.expect("OFFSET")
        offsets.append([tk.number("OFFSET x"), tk.number("OFFSET y"), tk.number("OFFSET z")])
        chans: tuple[str, ...] = ()
        if not is_end:
            tk.expect("CHANNELS")
            t, n = tk.next("channel count")
            if not t.isdigit():
                raise tk.error(f"expected the channel count, found {t!r}", n)
            chans = tuple(tk.next("channel name")[0] for _ in range(int(t)))
            for c in chans:
                if c not in _ROT and c not in _POS:
                    raise tk.error(f"unknown channel {c!r} of joint {name!r}", n)
        channels.append(chans)
        while True:
            t, n = tk.next("JOINT, End Site or }")
            if t == "}":
                return
            if is_end:
                raise tk.error(f"End Site of {names[parent]!r} has children ({t!r})", n)
            if t == "JOINT":
                joint(idx, False, tk.next("joint name")[0])
            elif t == "End":
                tk.expect("Site")
                joint(idx, True, f"{name}_end")
            else:
                raise tk.error(f"expected JOINT, End Site or '}}', found {t!r}", n)

    t, n = tk.next("ROOT")
    if t != "ROOT":
        raise tk.error(f"expected ROOT, found {t!r}", n)
    joint(-1, False, tk.next("root name")[0])
    if tk.i != len(tk.toks):
        raise tk.error(f"unexpected {tk.toks[tk.i][0]!r} after the root joint")
    return names, parents, offsets, channels


def _scale_for_units(path: Path, extent: float, units: str | None, scale: float) -> float:
    """Metres per file unit from ``units`` (``"auto"``: inferred from the rest skeleton's
    ``extent``, said on the console) or ``scale``; warns about an implausible size when
    neither was given."""
    if units == "auto":
        units = _unit_for_extent(extent) if extent > 0 else None
        if units is None:
            sizes = ", ".join(f"{extent * m:.3g} m in {u}" for u, m in _UNITS_M.items())
            raise FxspaceError(
                f"{path}: cannot infer the units: the rest skeleton spans {extent:.4g} units "
                f"({sizes}), no unit gives a person 1–3 m across; pass units=… or scale=… "
                "(CMU's BVH conversion: scale=0.0254/0.45)"
            )
        note(f"{path.name}: lengths inferred to be {units} (the rest skeleton spans "
             f"{extent:.4g} units: {extent * _UNITS_M[units]:.3g} m); read as metres "
             f"(declare units=… if not)")  # fmt: skip
        scale = _UNITS_M[units]
    elif units is not None:
        scale = _UNITS_M[units]
        note(f"{path.name}: lengths in {units} (declared), read as metres "
             f"(the rest skeleton spans {extent * scale:.3g} m)")  # fmt: skip
    elif scale == 1.0 and extent > 0 and not 0.3 <= extent <= 5.0:
        likely = _unit_for_extent(extent)
        if likely not in (None, "m"):
            note(f"{path.name}: the rest skeleton spans {extent:.4g} m read as metres (BVH "
                 f"declares no unit) — implausible for a body; the lengths look like {likely} "
                 f"({extent * _UNITS_M[likely]:.3g} m): read with units={likely!r}",
                 warning=True)  # fmt: skip
    return scale


def _read_frames(path, lines: list[str], mline: int, n_ch: int) -> tuple[np.ndarray, float]:
    """The MOTION section: ``(frames × channels data, frame time)``; errors name the line."""

    def header(k: int, key: str) -> tuple[str, int]:
        while k < len(lines) and not lines[k].strip():
            k += 1
        if k >= len(lines) or not lines[k].strip().startswith(key):
            raise CorruptFileError(f"{path}, line {k + 1}: expected '{key}'")
        return lines[k].strip()[len(key) :].strip(), k + 1

    val, k = header(mline + 1, "Frames:")
    try:
        n_frames = int(val)
    except ValueError:
        raise CorruptFileError(f"{path}, line {k}: bad frame count {val!r}") from None
    val, k = header(k, "Frame Time:")
    try:
        dt = float(val)
    except ValueError:
        raise CorruptFileError(f"{path}, line {k}: bad frame time {val!r}") from None
    if not np.isfinite(dt) or dt <= 0:
        raise CorruptFileError(
            f"{path}, line {k}: the frame time must be a finite positive number of seconds, "
            f"got {val!r}; fix the 'Frame Time:' line (e.g. 0.00833333 for 120 Hz)"
        )
    rows = []
    for ln_no in range(k, len(lines)):
        s = lines[ln_no].split()
        if not s:
            continue
        if len(s) != n_ch:
            raise CorruptFileError(
                f"{path}, line {ln_no + 1}: {len(s)} values, the hierarchy declares {n_ch} channels"
            )
        try:
            rows.append([float(x) for x in s])
        except ValueError:
            raise CorruptFileError(
                f"{path}, line {ln_no + 1}: non-numeric value in frame data"
            ) from None
    if len(rows) != n_frames:
        hint = "truncated file?" if len(rows) < n_frames else "fix the 'Frames:' line"
        raise CorruptFileError(
            f"{path}, line {len(lines)}: header says {n_frames} frames, found {len(rows)} ({hint})"
        )
    return np.asarray(rows, dtype=np.float64).reshape(n_frames, n_ch), dt


def _decode_channels(data: np.ndarray, channels, parents, offsets):
    """Channel columns → ``(quaternions (T, J, 4), root (T, 3), {joint: local translations})``."""
    n_frames = data.shape[0]
    J = len(channels)
    quats = np.zeros((n_frames, J, 4))
    quats[..., 0] = 1.0
    root = np.zeros((n_frames, 3))
    local = {}  # non-root joints with position channels: (T, 3) local translations
    col = 0
    for j, chans in enumerate(channels):
        order = "".join(_ROT[c] for c in chans if c in _ROT)
        rcols = [col + i for i, c in enumerate(chans) if c in _ROT]
        for i, c in enumerate(chans):
            if c in _POS:
                if parents[j] == -1:
                    root[:, _POS[c]] = data[:, col + i]
                else:
                    tr = local.setdefault(j, np.tile(np.asarray(offsets[j], float), (n_frames, 1)))
                    tr[:, _POS[c]] = data[:, col + i]
        if order:
            quats[:, j] = euler_to_quat(data[:, rcols], order)
        col += len(chans)
    return quats, root, local


def _fold_joint_translations(path, names, parents, offsets, root, quats, local) -> None:
    """Position channels on non-root joints (a BVH variant from game pipelines, e.g. the
    Bandai Namco dataset: 6 channels on every joint): the channel values replace the
    joint's OFFSET, frame by frame. A translation that stays constant (within 1e-6 of the
    file's length unit per frame) becomes the joint's offset; one that varies is folded
    into the root translation, which is exact for every joint but the root when the joint
    is the root's only child (``X_j = X_root + R_root t_j``; the root itself then sits at
    ``X_j − R_root OFFSET_j``). Anything else cannot be represented by a
    `Motion` (rigid bones) and raises ``CorruptFileError``. Edits in place."""
    children = [sum(1 for p in parents if p == j) for j in range(len(parents))]
    for j, tr in local.items():
        if np.ptp(tr, axis=0).max() <= 1e-6 * max(1.0, float(np.abs(tr).max())):
            offsets[j] = tr.mean(axis=0)
        elif parents[j] == 0 and children[0] == 1:
            root += np.asarray(quat_rotate(quats[:, 0], tr - offsets[j][None]))
        else:
            raise CorruptFileError(
                f"{path}: joint {names[j]!r} has time-varying position channels and is not "
                "the root's only child; a Motion has rigid bones, so this file cannot be read"
            )


def _fmt(x: float) -> str:
    s = f"{x:.6f}"
    return "0.000000" if s == "-0.000000" else s


@checked
def write_bvh(path: str | Path, motion: Motion, scale: float = 1.0) -> Path:
    """Write ``motion`` as BVH, each joint's Euler angles in the order of its ``channels``.

    Joints without channels that have no children are written as ``End Site``; a joint
    whose rotation channels are not three distinct axes must have identity rotation.
    Lengths are divided by ``scale`` (metres per file unit). Written atomically; ``.gz``
    paths are compressed. A ``scale`` or ``motion.rate`` that is not a finite positive
    number, or non-finite rotations/translations, raise `FxspaceError`.
    """
    from fxspace.runs import write_bytes_atomic

    scale = check_scalar(scale, "scale", low=0.0, low_open=True)
    check_scalar(motion.rate, "motion.rate", low=0.0, low_open=True)
    for what, arr in (("motion.rotations", motion.rotations), ("motion.offsets", motion.offsets),
                      ("motion.root_translation", motion.root_translation)):  # fmt: skip
        if not np.all(np.isfinite(np.asarray(arr))):
            raise FxspaceError(f"write_bvh: {what} holds NaN/inf; BVH cannot store them")
    path = Path(path)
    J = motion.num_joints
    children: list[list[int]] = [[] for _ in range(J)]
    for j, p in enumerate(motion.parents):
        if p >= 0:
            children[p].append(j)
    offsets = np.asarray(motion.offsets) / scale
    out: list[str] = ["HIERARCHY"]
    emitted: list[int] = []  # depth-first: the order a reader takes the channels in

    def emit(j: int, depth: int) -> None:
        emitted.append(j)
        ind = "\t" * depth
        chans = motion.channels[j]
        is_end = not chans and not children[j]
        if motion.parents[j] == -1:
            out.append(f"ROOT {motion.names[j]}")
        elif is_end:
            out.append(f"{ind}End Site")
        else:
            out.append(f"{ind}JOINT {motion.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET " + " ".join(_fmt(v) for v in offsets[j]))
        if not is_end:
            out.append(f"{ind}\tCHANNELS {len(chans)} " + " ".join(chans))
            for c in children[j]:
                emit(c, depth + 1)
        out.append(f"{ind}}}")

    emit(0, 0)
    T = motion.num_frames
    cols = []
    quats = np.asarray(motion.rotations)
    root = np.asarray(motion.root_translation) / scale
    for j in emitted:
        chans = motion.channels[j]
        order = "".join(_ROT[c] for c in chans if c in _ROT)
        if order and len(order) != 3:
            raise ValueError(
                f"motion.channels[{j}] ({motion.names[j]!r}) has rotation channels "
                f"{order!r}; write_bvh needs three distinct axes"
            )
        eul = quat_to_euler(quats[:, j], order) if order else None
        r = 0
        for c in chans:
            if c in _POS and motion.parents[j] == -1:
                cols.append(root[:, _POS[c]])
            elif c in _POS:  # a non-root joint's position channel: its (constant) offset
                cols.append(np.full(T, offsets[j, _POS[c]]))
            else:
                cols.append(eul[:, r])
                r += 1
    data = np.stack(cols, axis=1) if cols else np.zeros((T, 0))
    out += ["MOTION", f"Frames: {T}", f"Frame Time: {1.0 / motion.rate:.8f}"]
    out += [" ".join(_fmt(v) for v in row) for row in data]
    text = ("\n".join(out) + "\n").encode("utf-8")
    if path.suffix == ".gz":
        text = gzip.compress(text, mtime=0)
    return write_bytes_atomic(path, text)
