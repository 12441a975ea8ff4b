"""Run folders: config + seed + versions beside the results, every write atomic.

A run folder holds ``config.toml`` (the resolved config), ``meta.json`` (seed,
versions, git SHA, platform, device), ``metrics.json`` and figures (PNG). Files are
written to a temporary name in the same folder and renamed into place, so an
interrupted run never leaves a half-written file; ``metrics.json`` is written last
and marks the run complete. ``cached`` stores intermediate results so an
interrupted sweep resumes where it stopped; the cache belongs to one *run key* — a hash
of the resolved config, the data (file digests) and the code (`run_key`) — and is
cleared when the key changes, so a changed config, data file or code never reuses it.
``status.json`` says ``running``, ``complete``, ``failed`` (with the error) or
``interrupted``. Files are readable by the group (never 0600).

**A user's folders are theirs**: every file fxspace writes into a run folder is listed
in the folder's manifest ``.fxspace-manifest`` (one relative path a line, see `record`).
Clearing a cache (`reset_cache`) or an old run (`clean_run`) deletes only the files
listed there, and then only the folders that became empty; a file fxspace did not
write (say ``DIR/cache/notes.txt``) is never touched. Each manifest line keeps the
file's inode: a file is deleted only when it is still the very file fxspace wrote (a
regular file, its inode unchanged, reached without passing a symbolic link), so a
collaborator's symlink, a hand-edited manifest or a file replaced since never makes a
clean delete anything outside the run or anything a user wrote. fxspace never writes
through a symbolic link inside a run folder, and reads its bookkeeping files
(``status.json``, ``metrics.json``, the lock) only when they are regular files: a FIFO
of that name is refused with a message, never waited on.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import re
import stat
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from importlib import metadata
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
    "versions",
    "git_sha",
    "write_meta",
    "update_meta",
    "cached",
    "to_jsonable",
    "code_digest",
    "file_digest",
    "run_key",
    "write_status",
    "read_status",
    "reset_cache",
    "cached_arrays",
    "MANIFEST",
    "record",
    "manifest_files",
    "clean_run",
    "active_run",
    "unrecorded",
    "RunLockedError",
    "OverwriteRefusedError",
    "UnsafePathError",
    "check_writable",
    "read_regular",
    "read_json",
    "run_lock",
    "pid_alive",
    "LOCK",
    "machine",
    "BENCH_FIELDS",
    "write_bench",
    "bench_name_ok",
]

#: Name of the manifest file: the files fxspace wrote into a run folder.
MANIFEST = ".fxspace-manifest"
#: Name of a run folder's lock file (pid, host and time of the process running it).
LOCK = ".fxspace-lock"

# user-saved state: never deleted by a clean even where an older manifest lists it
_USER_STATE = frozenset({"edits.json"})
# the run folder being written by `run_dict` (files written under it are recorded)
_ACTIVE: ContextVar[_Active | None] = ContextVar("fxspace_active_run", default=None)
# manifest path -> {relative path: inode} already listed (a path is appended again only
# when fxspace has replaced the file, so the last line holds its current inode)
_LISTED: dict[Path, dict[str, int | None]] = {}
# run folders whose cache folder cannot be used (a link, a file, unwritable): their
# stages are computed without a cache (said once, when found)
_NO_CACHE: set[Path] = set()

_PACKAGES = (
    "fxspace",
    "jax",
    "jaxlib",
    "numpy",
    "scipy",
    "optax",
    "jaxopt",
    "optimistix",
    "matplotlib",
)


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


class RunLockedError(FxspaceError, RuntimeError):
    """Another live process holds the run folder's lock."""


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` lives on this host (one that exists but is not ours: yes)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OSError, ValueError, OverflowError):
        return False
    return True


def _lock_holder(text: bytes) -> dict[str, Any] | None:
    """The holder a lock file names (``pid``, ``host``, ``at``), or ``None`` for garbage."""
    try:
        held = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    if (
        isinstance(held, dict)
        and isinstance(held.get("pid"), int)
        and not isinstance(held.get("pid"), bool)
        and isinstance(held.get("host"), str)
    ):
        return held
    return None


def _unlink_if_same(p: Path, ino: int) -> None:
    """Delete ``p`` only if it is still the file (inode) that was looked at."""
    try:
        if os.lstat(p).st_ino == ino:
            p.unlink()
    except FileNotFoundError:
        pass


@contextmanager
def run_lock(run_dir: str | Path, wait: float | None = 0.0, poll: float = 0.2) -> Iterator[Path]:
    """Hold ``run_dir/.fxspace-lock`` (pid, host, time) while one process writes the run.

    A second process waits up to ``wait`` seconds (``None``: until it is free, saying
    whom it waits for) and then raises `RunLockedError` naming the holder and the fix. A
    lock whose holder died (same host, pid gone) is taken over, with a message, and so is
    a lock that names no holder (garbage such as ``garbage`` or ``{}``, or empty for more
    than 2 s). A lock that is not a regular file (a FIFO, a link, a folder) is refused
    with `UnsafePathError`, never read.
    """
    import socket
    import time

    root = Path(run_dir)
    root.mkdir(parents=True, exist_ok=True)
    lp = root / LOCK
    host = socket.gethostname()
    me = {"pid": os.getpid(), "host": host,
          "at": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")}  # fmt: skip
    t0 = time.monotonic()
    said = False
    nofollow = getattr(os, "O_NOFOLLOW", 0)
    while True:
        try:
            fd = os.open(lp, os.O_CREAT | os.O_EXCL | os.O_WRONLY | nofollow, 0o644)
        except FileExistsError:
            try:
                st = os.lstat(lp)
            except FileNotFoundError:
                continue  # released meanwhile
            if not stat.S_ISREG(st.st_mode):
                raise UnsafePathError(
                    f"{lp} is {_kind(st.st_mode)}, not fxspace's lock file; remove it "
                    "(fxspace makes its own) and rerun"
                ) from None
            try:
                text = read_regular(lp) or b""
            except (OSError, UnsafePathError):
                continue  # replaced meanwhile: look again
            held = _lock_holder(text)
            if held is None:
                if not text.strip() and time.time() - st.st_mtime < 2.0:
                    time.sleep(poll)  # being written right now
                    continue
                what = "is empty" if not text.strip() else "names no holder (not a lock)"
                print(f"[fxspace] {lp} {what}; treating it as stale and taking it over")
                _unlink_if_same(lp, st.st_ino)
                continue
            if held["host"] == host and not pid_alive(held["pid"]):
                print(f"[fxspace] {lp}: its holder (pid {held['pid']}) died; taking it over")
                _unlink_if_same(lp, st.st_ino)
                continue
            who = (
                f"pid {held['pid']} on {held['host']} since {held.get('at')}, lock {lp}"
            )
            if wait is not None and time.monotonic() - t0 >= wait:
                raise RunLockedError(
                    f"{root} is being written by another process ({who}); wait for it to "
                    "finish, or choose another --out; if that process is gone, delete the "
                    "lock file"
                ) from None
            if not said:
                limit = "until it is free" if wait is None else f"up to {wait:g} s"
                print(f"[fxspace] {root} is being written by another process ({who}); "
                      f"waiting {limit} (Ctrl-C stops)", flush=True)  # fmt: skip
                said = True
            time.sleep(poll)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(me))
        break
    try:
        yield lp
    finally:
        try:
            st = os.lstat(lp)
            held = _lock_holder(read_regular(lp) or b"") if stat.S_ISREG(st.st_mode) else None
            if held is not None and held["pid"] == os.getpid() and held["host"] == host:
                _unlink_if_same(lp, st.st_ino)
        except (OSError, UnsafePathError):
            pass


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


def _in_nested_run(root: Path, rel: str) -> bool:
    """Whether ``root/rel`` lies inside another run folder nested under ``root``."""
    d = root
    for part in Path(rel).parts[:-1]:
        d = d / part
        if (d / MANIFEST).is_file() or (d / "status.json").is_file() or (d / LOCK).exists():
            return True
    return False


def _deletion_order(rel: str) -> tuple[int, str]:
    # the files that say "finished" go first: a clean stopped part-way never leaves a
    # folder that a plain rerun calls complete
    return ({"metrics.json": 0, "status.json": 1}.get(rel, 2), rel)


def _remove_listed(root: Path, keep: Callable[[str], bool]) -> list[str]:
    """Delete the manifest's files for which ``keep(rel)`` is false, then the folders
    left empty by that (never a folder that still holds anything, never a file inside
    a nested run folder). A file is deleted only while it is the very file fxspace wrote:
    reached without passing a link, a regular file, its inode the one the manifest keeps;
    anything else is left, named in one message."""
    entries = _manifest_entries(root)
    removed, kept, left = [], [], []
    for rel in sorted(entries, key=_deletion_order):
        if _in_nested_run(root, rel) or Path(rel).name in _USER_STATE:
            continue  # another run's file, or the user's saved edits: never ours to delete
        if keep(rel):
            kept.append(rel)
            continue
        f = root / rel
        why = _unsafe_below(root, rel)
        if why is None:
            try:
                ino = os.lstat(f).st_ino
            except FileNotFoundError:
                removed.append(rel)  # already gone
                continue
            if entries[rel] is not None and ino != entries[rel]:
                why = f"{f} was replaced since fxspace wrote it"
        if why is not None:
            left.append(why)
            continue
        f.unlink()
        removed.append(rel)
        parent = f.parent
        while parent != root and _unsafe_below(root, parent.relative_to(root).as_posix(),
                                                final=False) is None:  # fmt: skip
            try:
                if any(parent.iterdir()):
                    break
                parent.rmdir()
            except OSError:
                break
            parent = parent.parent
    if left:
        print(f"[fxspace] left {len(left)} listed file(s) that are not fxspace's to delete: "
              + "; ".join(left[:5]) + (" …" if len(left) > 5 else ""))  # fmt: skip
    m = root / MANIFEST
    if kept:
        with unrecorded():
            write_text_atomic(
                m, "".join(r + ("" if entries[r] is None else f"\t{entries[r]}") + "\n"
                           for r in kept))  # fmt: skip
    elif m.exists():
        m.unlink()
    _LISTED.pop(m, None)
    return removed


def clean_run(run_dir: str | Path, keep: Callable[[str], bool] | None = None) -> list[str]:
    """Delete every file fxspace wrote into ``run_dir`` (its manifest), e.g. an old
    experiment's figures and arrays before another config runs there; files fxspace did not
    write, files replaced since, anything behind a symbolic link, and folders that still
    hold such files, stay. ``metrics.json`` goes first, so a clean stopped part-way never
    looks finished. Returns the removed relative paths."""
    root = Path(run_dir).resolve()
    if not root.is_dir():
        return []
    return _remove_listed(root, keep or (lambda rel: False))


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


def versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0]}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def git_sha() -> str | None:
    here = Path(__file__).resolve().parent.parent
    try:
        r = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
        sha = r.stdout.strip()
        if not sha:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def write_meta(run_dir: str | Path, seed: int, extra: dict[str, Any] | None = None) -> Path:
    import jax

    meta = {
        "seed": seed,
        "versions": versions(),
        "git_sha": git_sha(),
        "platform": platform.platform(),
        "device": str(jax.devices()[0]),
        "x64": bool(jax.config.read("jax_enable_x64")),
        "started": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "argv": sys.argv,
    }
    meta.update(extra or {})
    return write_json_atomic(Path(run_dir) / "meta.json", meta)


def update_meta(run_dir: str | Path, extra: dict[str, Any]) -> Path:
    """Merge ``extra`` into ``meta.json`` (e.g. the run's ``"timing"``: compile vs compute)."""
    p = Path(run_dir) / "meta.json"
    try:
        meta = read_json(p) or {}
    except (OSError, CorruptFileError):
        meta = {}  # fxspace's own bookkeeping, damaged: written again whole
    return write_json_atomic(p, {**meta, **extra})


def code_digest() -> str:
    """SHA-256 of fxspace's source files (paths + bytes): the code version of a run key."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def file_digest(path: str | Path, chunk: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def run_key(config_text: str, data_files: list[str | Path] = (), code: str | None = None) -> str:
    """The content key of a run: hash of the resolved config, data digests and code."""
    h = hashlib.sha256(config_text.encode())
    for f in sorted(str(Path(x)) for x in data_files):
        h.update(f.encode() + b"\0" + file_digest(f).encode())
    h.update((code if code is not None else code_digest()).encode())
    return h.hexdigest()


def write_status(run_dir: str | Path, status: str, **extra: Any) -> Path:
    """Write ``status.json`` (``running`` / ``complete`` / ``failed`` / ``interrupted`` /
    ``partial``: only the stages an app shows, `fxspace.pipelines.prepare_config`)."""
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    return write_json_atomic(Path(run_dir) / "status.json", {"status": status, "at": now, **extra})


def read_status(run_dir: str | Path) -> dict[str, Any]:
    """``status.json`` of a run folder (``{}`` when absent, or when it is not a JSON
    object: an unknown status, never "complete"). A FIFO or other non-regular file of
    that name is refused (`UnsafePathError`), never waited on."""
    try:
        return read_json(Path(run_dir) / "status.json") or {}
    except CorruptFileError:
        return {}
    except UnsafePathError:
        raise
    except OSError:
        return {}


def _read_key(kp: Path) -> str | None:
    try:
        data = read_regular(kp)
    except (OSError, UnsafePathError):
        return None
    if data is None:
        return None
    try:
        return data.decode("utf-8").strip()
    except UnicodeDecodeError:
        return "damaged"


def _cache_unusable(root: Path) -> str | None:
    """Why ``root/cache`` cannot hold this run's cache (``None``: it can)."""
    d = root / "cache"
    try:
        st = os.lstat(d)
    except FileNotFoundError:
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            return f"{root} cannot be written ({e.strerror or e})"
        return None if os.access(root, os.W_OK | os.X_OK) else f"{root} is not writable"
    except OSError as e:
        return f"{d} cannot be examined ({e.strerror or e})"
    if stat.S_ISLNK(st.st_mode):
        return (f"{d} is a symbolic link (to {os.readlink(d)}); fxspace keeps its cache "
                "in a real folder of the run, never behind a link")
    if not stat.S_ISDIR(st.st_mode):
        return f"{d} is {_kind(st.st_mode)}, not a folder"
    if not os.access(d, os.W_OK | os.X_OK):
        return f"{d} is not writable"
    return None


def _no_cache(root: Path, why: str) -> None:
    if root not in _NO_CACHE:
        print(f"[fxspace] {why}: this run computes every stage without a cache "
              "(nothing is resumed; remove or fix it to cache again)", flush=True)  # fmt: skip
    _NO_CACHE.add(root)


def reset_cache(run_dir: str | Path, key: str, force: bool = False) -> bool:
    """Bind ``run_dir/cache`` to the run key ``key``: clear it when the key differs (or on
    ``force``). Returns whether an existing cache was cleared.

    Clearing deletes only the cache files fxspace wrote (listed in the run folder's
    manifest, see `record`): a user's file under ``cache/`` survives. A cache folder
    that cannot be used — a symbolic link, a file of that name, read-only — is never
    written through nor cleared: the run goes on without a cache, saying why."""
    root = Path(run_dir)
    real = root.resolve()
    d = root / "cache"
    kp = d / "KEY"
    why = _cache_unusable(root)
    if why is not None:
        _no_cache(real, why)
        return False
    _NO_CACHE.discard(real)
    old = _read_key(kp)
    cleared = False
    if d.exists() and (force or old != key):
        listed = [r for r in manifest_files(root) if r.startswith("cache/")]
        if old is not None and not listed:
            # a cache from before manifests: nothing is known to be fxspace's, so nothing
            # is deleted; it is set aside so that no stale stage is ever served
            aside = d.with_name(f"cache.stale-{_dt.datetime.now(_dt.UTC):%Y%m%dT%H%M%S%f}")
            d.rename(aside)
            print(f"[fxspace] {d} predates run manifests; moved to {aside.name} (delete it freely)")
        else:
            _remove_listed(real, lambda rel: not rel.startswith("cache/"))
        cleared = True
    try:
        with unrecorded():
            write_text_atomic(kp, key + "\n")
        record(root, kp)
    except (OSError, FxspaceError) as e:
        _no_cache(real, f"{kp} cannot be written ({getattr(e, 'strerror', None) or e})")
    return cleared


def _cache_entry(run_dir: str | Path, p: Path) -> bytes | None:
    """The bytes of the cache entry ``p`` when it may be served: the run's cache is in
    use and ``p`` is a regular file fxspace wrote (listed, inode unchanged); else None."""
    root = Path(run_dir).resolve()
    if root in _NO_CACHE:
        return None
    rel = _rel_inside(root, p, Path(os.path.abspath(run_dir)))
    if rel is None or _unsafe_below(root, rel) is not None:
        return None
    entries = _manifest_entries(root)
    if rel not in entries:
        return None  # not fxspace's: never served (and never overwritten)
    try:
        if entries[rel] is not None and os.lstat(p).st_ino != entries[rel]:
            return None
        return read_regular(p)
    except (OSError, UnsafePathError):
        return None


def _store(run_dir: str | Path, p: Path, data: bytes) -> None:
    """Store a cache entry; a cache that cannot be written is said once, not fatal."""
    root = Path(run_dir).resolve()
    if root in _NO_CACHE:
        return
    act = _Active(Path(run_dir), False, None)
    rel = act.rel(p)
    try:
        if rel is not None:
            _check_ours(act, p, rel)
        with unrecorded():
            write_bytes_atomic(p, data)
        record(run_dir, p)
    except OverwriteRefusedError:
        print(f"[fxspace] {p} exists and fxspace did not write it: this stage is not "
              "cached (move that file to cache it)")  # fmt: skip
    except (OSError, FxspaceError) as e:
        _no_cache(root, f"{p} cannot be written ({getattr(e, 'strerror', None) or e})")


def cached(run_dir: str | Path, key: str, compute: Callable[[], Any]) -> Any:
    """Return the JSON result stored under ``key`` in ``run_dir/cache``, computing it once.

    Used by sweeps: each finished point is stored atomically, so re-running an
    interrupted sweep only computes the missing points. A damaged entry is recomputed;
    a cache folder that cannot be written is skipped with a message.
    """
    p = Path(run_dir) / "cache" / f"{key}.json"
    data = _cache_entry(run_dir, p)
    if data is not None:
        try:
            return json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            print(f"[fxspace] {p} is damaged; recomputing it")
    value = to_jsonable(compute())
    _store(run_dir, p, (json.dumps(value, indent=2) + "\n").encode("utf-8"))
    return value


def cached_arrays(
    run_dir: str | Path, name: str, compute: Callable[[], dict[str, Any]]
) -> dict[str, np.ndarray]:
    """A costly pipeline stage, stored once as ``run_dir/cache/NAME.npz`` (atomically).

    ``compute()`` returns a flat ``{name: array-like}``; the stored arrays are returned
    (as NumPy arrays) on this and every later call in the same run folder, so a run
    interrupted after this stage resumes without recomputing it. The cache folder is
    bound to the run's content key (config + data + code, see `reset_cache`), so a
    stage is never served to another config. A damaged file (truncated, not a zip,
    a member that does not decompress) is recomputed, with a message; a cache folder
    that cannot be written is skipped with a message.

    **Example:**

    ```python
    geo = cached_arrays(run_dir, "geodesics", lambda: {"D": D, "next_hop": nh})
    ```
    """
    import io

    if not isinstance(name, str) or not name or "/" in name or name.startswith("."):
        raise ValueError(f"stage name must be a plain file name, got {name!r}")
    p = Path(run_dir) / "cache" / f"{name}.npz"
    data = _cache_entry(run_dir, p)
    if data is not None:
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except Exception as e:  # noqa: BLE001 - BadZipFile, zlib.error, EOFError, ...
            print(f"[fxspace] {p} is damaged ({type(e).__name__}); recomputing it")
    value = {k: np.asarray(v) for k, v in compute().items()}
    buf = io.BytesIO()
    np.savez_compressed(buf, **value)
    _store(run_dir, p, buf.getvalue())
    return value


#: The fields of one benchmark comparison (a row of `write_bench`).
BENCH_FIELDS = ("case", "size", "ours", "ours_s", "peer", "peer_s", "ratio")


def machine() -> dict[str, Any]:
    """The machine a measurement ran on: host OS, CPU, core count, JAX devices, versions
    and the date (UTC), for benchmark records."""
    import jax

    devs = jax.devices()
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "devices": f"{len(devs)} x {devs[0].platform} ({devs[0].device_kind})",
        "python": platform.python_version(),
        "versions": versions(),
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


def write_bench(
    name: str,
    rows: list[dict[str, Any]],
    *,
    title: str,
    command: str,
    root: str | Path | None = None,
    force: bool = False,
) -> Path:
    """Write a benchmark's comparisons to ``root/bench/NAME.json`` (``root``: ``$FXSPACE_RUNS``
    or ``runs``) with the machine it ran on, for the docs' benchmark page (`fxspace docs`).

    Each row is one comparison, `BENCH_FIELDS`: ``case`` (a label), ``size`` (a number to
    plot against, or ``None``), ``ours`` / ``peer`` (what was timed), ``ours_s`` /
    ``peer_s`` (median seconds) and ``ratio`` (``peer_s / ours_s``, filled in when left out).

    ``name`` must be a plain file name (`bench_name_ok`). An existing ``NAME.json`` that
    fxspace did not write (not in ``bench/``'s manifest, not a benchmark record of that
    name) is refused (`OverwriteRefusedError`) unless ``force``.
    """
    if not bench_name_ok(name):
        raise FxspaceError(
            f"write_bench: name must be a plain file name (letters, digits, _ . -, no "
            f"folder, no '..'), got {name!r}"
        )
    if not rows:
        raise FxspaceError(f"write_bench({name!r}): rows is empty; pass one dict per comparison")
    out = []
    for i, r in enumerate(rows):
        missing = [k for k in ("case", "ours", "ours_s", "peer", "peer_s") if k not in r]
        if missing:
            raise FxspaceError(
                f"write_bench({name!r}): rows[{i}] lacks {missing}; each row needs "
                f"{', '.join(BENCH_FIELDS)} (size and ratio may be left out)"
            )
        r = {k: r.get(k) for k in BENCH_FIELDS}
        r["ours_s"], r["peer_s"] = float(r["ours_s"]), float(r["peer_s"])
        if r["ratio"] is None:
            r["ratio"] = r["peer_s"] / r["ours_s"] if r["ours_s"] > 0 else None
        out.append(r)
    root = Path(root if root is not None else os.environ.get("FXSPACE_RUNS", "runs"))
    rec = {"name": name, "title": title, "command": command.strip(), "machine": machine(),
           "rows": out}  # fmt: skip
    folder = root / "bench"
    with active_run(folder, force=force, recognise=_is_bench_record):
        try:
            return write_json_atomic(folder / f"{name}.json", to_jsonable(rec))
        except OverwriteRefusedError:
            raise OverwriteRefusedError(
                f"{folder / (name + '.json')} exists and is not a benchmark record fxspace "
                "wrote; nothing was written: move that file away, or set FXSPACE_RUNS to "
                "another folder (write_bench(..., force=True) replaces it)"
            ) from None


def bench_name_ok(name: Any) -> bool:
    """Whether ``name`` may name a benchmark record (``runs/bench/NAME.json``) and its
    figure: a plain file name, never a path, an absolute name or ``..``."""
    return (
        isinstance(name, str)
        and re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}", name) is not None
        and ".." not in name
    )


def _is_bench_record(p: Path) -> bool:
    """A benchmark record fxspace wrote before records were listed in a manifest: a JSON
    object with the record's keys whose ``name`` is the file's stem."""
    try:
        rec = read_json(p)
    except (OSError, FxspaceError):
        return False
    return (
        isinstance(rec, dict)
        and {"name", "title", "command", "machine", "rows"} <= set(rec)
        and rec.get("name") == p.stem
    )
