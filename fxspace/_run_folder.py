"""Run folders: their lock, status, meta and clean.

A run folder holds ``config.toml`` (the resolved config), ``meta.json`` (seed,
versions, git SHA, platform, device, `write_meta`), ``metrics.json`` and figures.
``status.json`` says ``running``, ``complete``, ``failed`` (with the error) or
``interrupted`` (`write_status`). One process writes a run at a time: it holds the
folder's lock ``.fxspace-lock`` (`run_lock`: pid, host and time; a dead holder's lock
is taken over). `clean_run` deletes only the files listed in the folder's manifest
(`fxspace.runs.record`), and then only the folders that became empty: a file fxspace
did not write is never touched.

The public front is `fxspace.runs`, which re-exports every name here.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import stat
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Any

from fxspace._atomic import (
    _LISTED,
    MANIFEST,
    UnsafePathError,
    _kind,
    _manifest_entries,
    _unsafe_below,
    read_json,
    read_regular,
    unrecorded,
    write_json_atomic,
    write_text_atomic,
)
from fxspace.errors import CorruptFileError, FxspaceError

__all__ = [
    "sweep_threshold",
    "versions",
    "git_sha",
    "write_meta",
    "update_meta",
    "write_status",
    "read_status",
    "clean_run",
    "RunLockedError",
    "run_lock",
    "pid_alive",
    "LOCK",
]

#: Name of a run folder's lock file (pid, host and time of the process running it).
LOCK = ".fxspace-lock"

# user-saved state: never deleted by a clean even where an older manifest lists it
_USER_STATE = frozenset({"edits.json"})

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


def sweep_threshold(run_dir: str | Path) -> tuple[float, str]:
    """``(ε, criterion)`` chosen by a finished threshold-sweep run (its ``metrics.json``:
    ``best_threshold`` and ``criterion``). Raises ``FxspaceError`` naming what is missing."""
    p = Path(run_dir)
    m = p / "metrics.json"
    if not m.is_file():
        raise FxspaceError(
            f"threshold = 'from:{run_dir}': {m} not found; run the sweep first "
            "(fxspace run configs/threshold_sweep.toml)"
        )
    metrics = json.loads(m.read_text())
    if "best_threshold" not in metrics:
        raise FxspaceError(f"{m} has no best_threshold: not a threshold_sweep run")
    return float(metrics["best_threshold"]), str(metrics.get("criterion", "?"))
