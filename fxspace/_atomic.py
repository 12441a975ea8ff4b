"""Atomic writes and safe reads: what every layer of fxspace may use to write a file.

A file is written to a temporary name in the same folder and renamed into place, so an
interrupted write never leaves a half-written file (`write_bytes_atomic` and its text,
JSON, figure and ``.npz`` forms). Files are readable by the group (never 0600).

Inside a run (`active_run`), every file written here under the run folder is listed in
the folder's manifest ``.fxspace-manifest`` (one relative path and its inode a line,
`record`); a file fxspace did not write is never replaced (`OverwriteRefusedError`,
unless ``--force``), and fxspace never writes through a symbolic link inside the folder
(`UnsafePathError`). Reads of fxspace's own bookkeeping (`read_regular`, `read_json`)
refuse anything but a regular file: a FIFO is refused with a message, never waited on.

The public front is `fxspace.runs`, which re-exports every name here.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np

from fxspace.errors import CorruptFileError, FxspaceError

__all__ = [
    "write_bytes_atomic",
    "write_text_atomic",
    "write_json_atomic",
    "save_figure_atomic",
    "save_npz_atomic",
    "to_jsonable",
    "MANIFEST",
    "record",
    "manifest_files",
    "active_run",
    "unrecorded",
    "OverwriteRefusedError",
    "UnsafePathError",
    "check_writable",
    "read_regular",
    "read_json",
]

#: Name of the manifest file: the files fxspace wrote into a run folder.
MANIFEST = ".fxspace-manifest"

# the run folder being written by `run_dict` (files written under it are recorded)
_ACTIVE: ContextVar[_Active | None] = ContextVar("fxspace_active_run", default=None)
# manifest path -> {relative path: inode} already listed (a path is appended again only
# when fxspace has replaced the file, so the last line holds its current inode)
_LISTED: dict[Path, dict[str, int | None]] = {}


class OverwriteRefusedError(FxspaceError, FileExistsError):
    """A file exists where fxspace would write and fxspace did not write it (it is not
    in the folder's manifest): never overwritten without ``--force``."""


class UnsafePathError(FxspaceError):
    """A symbolic link, FIFO or other non-regular file where fxspace reads or writes its
    own files: refused (never followed out of the folder, never waited on)."""


class _Active:
    """The folder being written (`active_run`): its real and its lexical absolute path,
    whether ``--force`` allows replacing files fxspace did not write, and an optional
    ``recognise(path)`` that knows fxspace's own output from before manifests."""

    def __init__(self, root: Path, force: bool, recognise: Callable[[Path], bool] | None):
        self.root = Path(os.path.realpath(root))
        self.lexical = Path(os.path.abspath(root))
        self.force = force
        self.recognise = recognise

    def rel(self, p: Path) -> str | None:
        return _rel_inside(self.root, p, self.lexical)


def _rel_inside(root: Path, p: str | Path, lexical: Path | None = None) -> str | None:
    """``p`` relative to the folder ``root`` (real path) as written — never by
    following a link below ``root`` — or ``None`` when ``p`` lies outside it."""
    ap = Path(os.path.abspath(p))
    for base in (lexical, root):
        if base is None:
            continue
        try:
            rel = ap.relative_to(base).as_posix()
        except ValueError:
            continue
        return rel if rel != "." else None
    try:  # reached through another name of the folder (a link above it)
        parent = Path(os.path.realpath(ap.parent)).relative_to(root)
    except ValueError:
        return None
    return (parent / ap.name).as_posix()


def _kind(mode: int) -> str:
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def _unsafe_below(root: Path, rel: str, final: bool = True) -> str | None:
    """Why ``root/rel`` may not be written or deleted by fxspace (``None``: it may): a
    folder on the way that is a symbolic link or not a folder, or (``final``) the file
    itself being a link, FIFO or folder. Checked with ``lstat``, never following links."""
    d = root
    parts = Path(rel).parts
    for i, part in enumerate(parts):
        d = d / part
        try:
            st = os.lstat(d)
        except FileNotFoundError:
            return None  # the rest does not exist yet: fxspace makes it
        except OSError as e:
            return f"{d} cannot be examined ({e.strerror or e})"
        last = i == len(parts) - 1
        if last:
            if final and not stat.S_ISREG(st.st_mode):
                what = _kind(st.st_mode)
                if stat.S_ISLNK(st.st_mode):
                    what += f" (to {os.readlink(d)})"
                return f"{d} is {what}, not a file fxspace wrote"
        elif not stat.S_ISDIR(st.st_mode):
            what = _kind(st.st_mode)
            if stat.S_ISLNK(st.st_mode):
                what += f" (to {os.readlink(d)})"
            return f"{d} is {what}, not a folder fxspace made"
    return None


def write_bytes_atomic(path: str | Path, data: bytes, mode: int | None = None) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder + rename), with
    the usual mode (``0o666 & ~umask``) or ``mode``, set before the file appears.

    Inside a run (`active_run`), a path under the run folder is written only when no
    folder on the way is a symbolic link (`UnsafePathError`: fxspace never writes out of
    its folder through a link) and, when the file exists, when fxspace wrote it (its
    manifest lists it; else `OverwriteRefusedError` naming the fix)."""
    p = Path(path)
    active = _ACTIVE.get()
    rel = active.rel(p) if active is not None else None
    if active is not None and rel is not None:
        _check_ours(active, p, rel)
    p.parent.mkdir(parents=True, exist_ok=True)
    # a short unique temp name beside the target: never NAME.tmp (a user's file of that
    # name survives) and short enough for any legal (255-character) target name
    fd, tmp = tempfile.mkstemp(prefix=".fx", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        # mkstemp makes 0600; use the usual mode (or the one asked for)
        os.chmod(tmp, (0o666 & ~_umask()) if mode is None else mode)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    if active is not None and rel is not None:
        record(active.root, p)
    return p


def _check_ours(active: _Active, p: Path, rel: str) -> None:
    """Inside a run, a path under the run folder is written only through real folders,
    and an existing file there is replaced only when the folder's manifest lists it
    (fxspace wrote it), it is recognisably fxspace's own output, or ``--force``."""
    why = _unsafe_below(active.root, rel, final=False)
    if why is not None:
        raise UnsafePathError(
            f"{why}: fxspace never writes through a link inside {active.lexical}; "
            "remove the link (fxspace makes its own folder there) or choose another --out"
        )
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode):
        raise UnsafePathError(
            f"{p} is {_kind(st.st_mode)}; fxspace writes only regular files of its own "
            "there: move it away, or choose another --out"
        )
    if active.force or rel in _manifest_entries(active.root):
        return
    if active.recognise is not None and active.recognise(p):
        return
    raise OverwriteRefusedError(
        f"{p} exists and this run did not write it (it is not in "
        f"{active.lexical / MANIFEST}); fxspace never overwrites a file it did not write: "
        "move or rename that file, choose another --out, or pass --force to replace it"
    )


def check_writable(
    folder: str | Path,
    paths: list[str | Path],
    force: bool = False,
    recognise: Callable[[Path], bool] | None = None,
) -> None:
    """Refuse, before anything is written, to replace any of ``paths`` (under
    ``folder``) that fxspace did not write: `OverwriteRefusedError` naming them and the
    fix, or `UnsafePathError` for a link on the way. ``force``: replace them (links and
    FIFOs are still refused). ``recognise(path)``: fxspace's own output from before
    manifests (e.g. a page carrying the generated-page line)."""
    act = _Active(Path(folder), force, recognise)
    theirs = []
    for p in map(Path, paths):
        rel = act.rel(p)
        if rel is None:
            continue
        try:
            _check_ours(act, p, rel)
        except OverwriteRefusedError:
            theirs.append(p)
    if theirs:
        names = ", ".join(str(p) for p in theirs[:5]) + (" …" if len(theirs) > 5 else "")
        raise OverwriteRefusedError(
            f"{names} exist{'s' if len(theirs) == 1 else ''} and fxspace did not write "
            f"{'it' if len(theirs) == 1 else 'them'} (not in {act.lexical / MANIFEST}); "
            "nothing was written: move them away, choose another --out, or pass --force "
            "to replace them"
        )


def read_regular(path: str | Path) -> bytes | None:
    """The bytes of ``path`` — ``None`` when it does not exist — refusing anything but a
    regular file (`UnsafePathError`): a FIFO is opened without blocking and refused, never
    waited on; a folder or device named like a file is refused."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        return None
    except IsADirectoryError:
        raise UnsafePathError(f"{path} is a folder, not a file; move it away") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafePathError(
                f"{path} is {_kind(st.st_mode)}, not a regular file: fxspace never reads "
                "one (it could wait forever); remove it, fxspace writes its own"
            )
        chunks = []
        while block := os.read(fd, 1 << 20):
            chunks.append(block)
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_json(path: str | Path, kind: type = dict) -> Any:
    """``path`` parsed as JSON (``None`` when absent), refusing a non-regular file
    (`UnsafePathError`) and, with a `CorruptFileError` naming the file, bytes that are
    not UTF-8 JSON or a value that is not a ``kind`` (a ``dict`` by default)."""
    data = read_regular(path)
    if data is None:
        return None
    try:
        value = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise CorruptFileError(f"{path} is not UTF-8 text (not JSON)") from None
    except json.JSONDecodeError as e:
        raise CorruptFileError(
            f"{path} is not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})"
        ) from None
    if not isinstance(value, kind):
        raise CorruptFileError(
            f"{path} holds a JSON {type(value).__name__}, not a {kind.__name__}"
        )
    return value


@contextmanager
def unrecorded() -> Iterator[None]:
    """Within this block, files written through this module are not recorded in the
    active run's manifest: user-owned state (the editor's ``edits.json``) that no
    ``--force`` or stale-run clean may delete."""
    token = _ACTIVE.set(None)
    try:
        yield
    finally:
        _ACTIVE.reset(token)


def _manifest_path(run_dir: str | Path) -> Path:
    return Path(run_dir).resolve() / MANIFEST


def _manifest_entries(run_dir: str | Path) -> dict[str, int | None]:
    """``{relative path: inode}`` of the manifest (the last line of a path wins; ``None``
    for a line without an inode, from before inodes were kept)."""
    m = _manifest_path(run_dir)
    try:
        data = read_regular(m)
    except (OSError, UnsafePathError):
        return {}
    # a damaged line (not UTF-8) names no file of ours; the other lines still count
    lines = data.decode("utf-8", "replace").splitlines() if data is not None else []
    out: dict[str, int | None] = {}
    for ln in lines:
        rel, _, ino = ln.partition("\t")
        if _safe_rel(rel):
            out[rel] = int(ino) if ino.isdigit() else None
    return out


def manifest_files(run_dir: str | Path) -> list[str]:
    """The files fxspace wrote into ``run_dir`` (paths relative to it, sorted), read from
    its manifest; ``[]`` when there is none (nothing is then known to be fxspace's)."""
    return sorted(_manifest_entries(run_dir))


def _safe_rel(rel: str) -> bool:
    """A manifest line is trusted only as a plain relative path inside the folder."""
    if not rel or rel.startswith(("/", "\\")) or "\0" in rel:
        return False
    parts = Path(rel).parts
    return bool(parts) and ".." not in parts and rel != MANIFEST


def record(run_dir: str | Path, path: str | Path) -> None:
    """List ``path`` (a file fxspace wrote, inside ``run_dir``) in the folder's manifest,
    with its inode (so a clean deletes it only while it is still that file).

    Paths outside ``run_dir``, or reached through a link below it, are ignored. The
    manifest is append-only, one ``relative path<TAB>inode`` a line, so an interrupted
    run loses at most the line being written.
    """
    root = Path(os.path.realpath(run_dir))
    rel = _rel_inside(root, path, Path(os.path.abspath(run_dir)))
    if rel is None or not _safe_rel(rel) or _unsafe_below(root, rel) is not None:
        return
    try:
        ino: int | None = os.lstat(root / rel).st_ino
    except OSError:
        ino = None
    m = root / MANIFEST
    listed = _LISTED.get(m)
    if listed is None or not m.is_file():
        listed = _LISTED[m] = _manifest_entries(root)
    if rel in listed and (ino is None or listed[rel] == ino):
        return
    root.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(m, flags | getattr(os, "O_NONBLOCK", 0), 0o666)
    except OSError as e:  # a link (ELOOP) or a FIFO nobody reads (ENXIO) named like it
        raise UnsafePathError(
            f"{m} cannot be used as fxspace's manifest ({e.strerror or e}); it must be a "
            "regular file fxspace made: remove it and rerun"
        ) from None
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise UnsafePathError(f"{m} is not a regular file; remove it and rerun")
        f.write(rel + ("" if ino is None else f"\t{ino}") + "\n")
    listed[rel] = ino


@contextmanager
def active_run(
    run_dir: str | Path,
    force: bool = False,
    recognise: Callable[[Path], bool] | None = None,
) -> Iterator[Path]:
    """Within this block, every file written through this module under ``run_dir`` is
    recorded in its manifest (figures, arrays, metrics of a pipeline's ``run``), and an
    existing file there that fxspace did not write is refused (`OverwriteRefusedError`)
    unless ``force`` or ``recognise(path)`` (fxspace's own output from before manifests)."""
    act = _Active(Path(run_dir), force, recognise)
    token = _ACTIVE.set(act)
    try:
        yield act.root
    finally:
        _ACTIVE.reset(token)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_bytes_atomic(path, text.encode("utf-8"))


def to_jsonable(obj: Any) -> Any:
    """Arrays → lists, numpy scalars → Python, NaN/inf kept as JSON's NaN/Infinity."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "__array__") and not isinstance(obj, str | bytes):
        arr = np.asarray(obj)
        return arr.item() if arr.ndim == 0 else arr.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json_atomic(path: str | Path, obj: Any) -> Path:
    return write_text_atomic(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=False) + "\n")


def save_figure_atomic(fig: Any, path: str | Path, dpi: int = 120) -> Path:
    """Save a matplotlib figure to PNG atomically and close it."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue())


def save_npz_atomic(path: str | Path, **arrays: Any) -> Path:
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return write_bytes_atomic(path, buf.getvalue())
