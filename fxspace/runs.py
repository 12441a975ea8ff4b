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
write (say ``DIR/cache/notes.txt``) is never touched.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
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

from fxspace.errors import FxspaceError

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
    "run_lock",
    "LOCK",
    "collect",
    "write_report",
    "machine",
    "BENCH_FIELDS",
    "write_bench",
]

#: Name of the manifest file: the files fxspace wrote into a run folder.
MANIFEST = ".fxspace-manifest"
#: Name of a run folder's lock file (pid, host and time of the process running it).
LOCK = ".fxspace-lock"

# user-saved state: never deleted by a clean even where an older manifest lists it
_USER_STATE = frozenset({"edits.json"})
# the run folder being written by `run_dict` (files written under it are recorded)
_ACTIVE: ContextVar[Path | None] = ContextVar("fxspace_active_run", default=None)
# manifest path -> the relative paths already listed (so each path is appended once)
_LISTED: dict[Path, set[str]] = {}

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


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder + rename)."""
    p = Path(path)
    active = _ACTIVE.get()
    if active is not None and (p.exists() or p.is_symlink()):
        _check_ours(active, p)
    p.parent.mkdir(parents=True, exist_ok=True)
    # a short unique temp name beside the target: never NAME.tmp (a user's file of that
    # name survives) and short enough for any legal (255-character) target name
    fd, tmp = tempfile.mkstemp(prefix=".fx", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; use the usual mode
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    if active is not None:
        record(active, p)
    return p


def _check_ours(root: Path, p: Path) -> None:
    """Inside a run, an existing file under the run folder may be replaced only when the
    folder's manifest lists it (fxspace wrote it); a user's file is never overwritten."""
    try:
        rel = p.resolve().relative_to(root).as_posix()
    except ValueError:
        return  # outside the run folder: not the run's business
    if rel in set(manifest_files(root)):
        return
    raise FileExistsError(
        f"{p} exists and this run did not write it (it is not in {root / MANIFEST}); "
        "fxspace never overwrites a file it did not write: move or rename that file, "
        "or choose another --out"
    )


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


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OSError, ValueError, OverflowError):
        return False
    return True


@contextmanager
def run_lock(run_dir: str | Path, wait: float | None = 0.0, poll: float = 0.2) -> Iterator[Path]:
    """Hold ``run_dir/.fxspace-lock`` (pid, host, time) while one process writes the run.

    A second process waits up to ``wait`` seconds (``None``: forever) and then raises
    `RunLockedError` naming the holder and the fix. A lock whose holder died (same host,
    pid gone) is taken over, with a message.
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
    while True:
        try:
            fd = os.open(lp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                held = json.loads(lp.read_text())
            except (OSError, json.JSONDecodeError):
                held = {}
            if (
                held.get("host") == host
                and isinstance(held.get("pid"), int)
                and (not _pid_alive(held["pid"]))
            ):
                print(f"[fxspace] {lp}: its holder (pid {held['pid']}) died; taking it over")
                try:
                    lp.unlink()
                except FileNotFoundError:
                    pass
                continue
            if not held and lp.exists():
                time.sleep(poll)  # being written right now
                if not lp.exists() or lp.read_text().strip():
                    continue
            if wait is not None and time.monotonic() - t0 >= wait:
                raise RunLockedError(
                    f"{root} is being written by another process (pid {held.get('pid')} on "
                    f"{held.get('host')} since {held.get('at')}, lock {lp}); wait for it to "
                    "finish, or choose another --out; if that process is gone, delete the "
                    "lock file"
                ) from None
            time.sleep(poll)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(me))
        break
    try:
        yield lp
    finally:
        try:
            if json.loads(lp.read_text()).get("pid") == os.getpid():
                lp.unlink()
        except (OSError, json.JSONDecodeError):
            pass


def _manifest_path(run_dir: str | Path) -> Path:
    return Path(run_dir).resolve() / MANIFEST


def manifest_files(run_dir: str | Path) -> list[str]:
    """The files fxspace wrote into ``run_dir`` (paths relative to it, sorted), read from
    its manifest; ``[]`` when there is none (nothing is then known to be fxspace's)."""
    m = _manifest_path(run_dir)
    try:
        lines = m.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return []
    return sorted({ln for ln in lines if _safe_rel(ln)})


def _safe_rel(rel: str) -> bool:
    """A manifest line is trusted only as a plain relative path inside the folder."""
    if not rel or rel.startswith(("/", "\\")) or "\0" in rel:
        return False
    parts = Path(rel).parts
    return bool(parts) and ".." not in parts and rel != MANIFEST


def record(run_dir: str | Path, path: str | Path) -> None:
    """List ``path`` (a file fxspace wrote, inside ``run_dir``) in the folder's manifest.

    Paths outside ``run_dir`` are ignored. The manifest is append-only, one relative
    path a line, so an interrupted run loses at most the line being written.
    """
    root = Path(run_dir).resolve()
    try:
        rel = Path(path).resolve().relative_to(root).as_posix()
    except ValueError:
        return
    if not _safe_rel(rel):
        return
    m = root / MANIFEST
    listed = _LISTED.get(m)
    if listed is None or not m.is_file():
        listed = _LISTED[m] = set(manifest_files(root))
    if rel in listed:
        return
    root.mkdir(parents=True, exist_ok=True)
    with m.open("a", encoding="utf-8") as f:
        f.write(rel + "\n")
    listed.add(rel)


@contextmanager
def active_run(run_dir: str | Path) -> Iterator[Path]:
    """Within this block, every file written through this module under ``run_dir`` is
    recorded in its manifest (figures, arrays, metrics of a pipeline's ``run``)."""
    root = Path(run_dir).resolve()
    token = _ACTIVE.set(root)
    try:
        yield root
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


def _remove_listed(root: Path, keep: Callable[[str], bool]) -> list[str]:
    """Delete the manifest's files for which ``keep(rel)`` is false, then the folders
    left empty by that (never a folder that still holds anything, never a file inside
    a nested run folder)."""
    listed = manifest_files(root)
    removed, kept = [], []
    for rel in listed:
        if _in_nested_run(root, rel) or Path(rel).name in _USER_STATE:
            continue  # another run's file, or the user's saved edits: never ours to delete
        if keep(rel):
            kept.append(rel)
            continue
        f = root / rel
        if f.is_file() or f.is_symlink():
            f.unlink()
        removed.append(rel)
        parent = f.parent
        while parent != root and parent.is_dir() and not any(parent.iterdir()):
            parent.rmdir()
            parent = parent.parent
    m = root / MANIFEST
    if kept:
        write_text_atomic(m, "".join(r + "\n" for r in kept))
    elif m.exists():
        m.unlink()
    _LISTED.pop(m, None)
    return removed


def clean_run(run_dir: str | Path, keep: Callable[[str], bool] | None = None) -> list[str]:
    """Delete every file fxspace wrote into ``run_dir`` (its manifest), e.g. an old
    experiment's figures and arrays before another config runs there; files fxspace did not
    write, and folders that still hold them, stay. Returns the removed relative paths."""
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
        meta = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        meta = {}
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
    """``status.json`` of a run folder (``{}`` when absent or unreadable)."""
    try:
        return json.loads((Path(run_dir) / "status.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def reset_cache(run_dir: str | Path, key: str, force: bool = False) -> bool:
    """Bind ``run_dir/cache`` to the run key ``key``: clear it when the key differs (or on
    ``force``). Returns whether an existing cache was cleared.

    Clearing deletes only the cache files fxspace wrote (listed in the run folder's
    manifest, see `record`): a user's file under ``cache/`` survives."""
    root = Path(run_dir)
    d = root / "cache"
    kp = d / "KEY"
    old = kp.read_text().strip() if kp.is_file() else None
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
            _remove_listed(root.resolve(), lambda rel: not rel.startswith("cache/"))
        cleared = True
    write_text_atomic(kp, key + "\n")
    record(root, kp)
    return cleared


def cached(run_dir: str | Path, key: str, compute: Callable[[], Any]) -> Any:
    """Return the JSON result stored under ``key`` in ``run_dir/cache``, computing it once.

    Used by sweeps: each finished point is stored atomically, so re-running an
    interrupted sweep only computes the missing points.
    """
    p = Path(run_dir) / "cache" / f"{key}.json"
    if p.is_file():
        try:
            return json.loads(p.read_text())
        except json.JSONDecodeError:
            pass  # a damaged cache entry is recomputed
    value = to_jsonable(compute())
    write_json_atomic(p, value)
    record(run_dir, p)
    return value


def cached_arrays(
    run_dir: str | Path, name: str, compute: Callable[[], dict[str, Any]]
) -> dict[str, np.ndarray]:
    """A costly pipeline stage, stored once as ``run_dir/cache/NAME.npz`` (atomically).

    ``compute()`` returns a flat ``{name: array-like}``; the stored arrays are returned
    (as NumPy arrays) on this and every later call in the same run folder, so a run
    interrupted after this stage resumes without recomputing it. The cache folder is
    bound to the run's content key (config + data + code, see `reset_cache`), so a
    stage is never served to another config. A damaged file is recomputed.

    **Example:**

    ```python
    geo = cached_arrays(run_dir, "geodesics", lambda: {"D": D, "next_hop": nh})
    ```
    """
    if not isinstance(name, str) or not name or "/" in name or name.startswith("."):
        raise ValueError(f"stage name must be a plain file name, got {name!r}")
    p = Path(run_dir) / "cache" / f"{name}.npz"
    if p.is_file():
        try:
            with np.load(p, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError):
            pass  # a damaged stage is recomputed
    value = {k: np.asarray(v) for k, v in compute().items()}
    save_npz_atomic(p, **value)
    record(run_dir, p)
    return value


# ------------------------------------------------------------------ comparing runs


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _scalar(v: Any) -> bool:
    return isinstance(v, int | float | str) and not isinstance(v, bool) or isinstance(v, bool)


def _run_folders(root: Path) -> list[Path]:
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        dirnames[:] = sorted(n for n in dirnames if n != "report" and not n.startswith("."))
        if "status.json" in filenames or "metrics.json" in filenames:
            found.append(d)
    return sorted(found)


def collect(run_dir: str | Path, as_frame: bool = False) -> Any:
    """One row per run under ``run_dir`` (every folder holding ``status.json`` or
    ``metrics.json``): ``run`` (its path relative to ``run_dir``), the swept keys (the
    config keys whose values differ between the runs, dotted), the scalar metrics,
    ``wall_s`` / ``compile_s`` (``meta.json`` timing), ``status`` and ``error``.

    Returns a list of dicts, or a pandas DataFrame with ``as_frame=True`` (needs pandas).
    A missing value is ``None`` (NaN in the frame), never 0.
    """
    rows, _, _ = _collect(run_dir)
    if as_frame:
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("collect(as_frame=True) needs pandas: pip install pandas") from None
        return pd.DataFrame(rows, columns=list(rows[0]) if rows else None)
    return rows


def _collect(run_dir: str | Path) -> tuple[list[dict[str, Any]], list[str], list[str]]:
    """The rows of `collect` plus the swept keys and the metric columns."""
    import tomllib

    root = Path(run_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"run_dir {root} is not a folder; pass a sweep's --out folder")
    runs = []
    for d in _run_folders(root):
        try:
            cfg = _flatten(tomllib.loads((d / "config.toml").read_text()))
        except (OSError, tomllib.TOMLDecodeError):
            cfg = {}
        try:
            metrics = json.loads((d / "metrics.json").read_text())
        except (OSError, json.JSONDecodeError):
            metrics = {}
        try:
            timing = json.loads((d / "meta.json").read_text()).get("timing") or {}
        except (OSError, json.JSONDecodeError):
            timing = {}
        st = read_status(d)
        runs.append((d, cfg, metrics, timing, st))
    keys = sorted({k for _, c, *_ in runs for k in c})
    swept = [
        k for k in keys
        if len({json.dumps(c.get(k), sort_keys=True) for _, c, *_ in runs}) > 1
    ]  # fmt: skip
    rows = []
    for d, cfg, metrics, timing, st in runs:
        row: dict[str, Any] = {"run": d.relative_to(root).as_posix() or "."}
        for k in swept:
            v = cfg.get(k)
            row[k] = v if _scalar(v) or v is None else json.dumps(v)
        for k, v in _flatten(metrics).items():
            if _scalar(v) and k not in row:
                row[k] = v
        row["wall_s"] = timing.get("wall_s", metrics.get("wall_time_s"))
        row["compile_s"] = timing.get("compile_s")
        status = st.get("status") or ("complete" if metrics else "unknown")
        row["status"] = status
        row["error"] = st.get("error")
        rows.append(row)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    rows = [{k: r.get(k) for k in cols} for r in rows]
    fixed = {"run", "wall_s", "compile_s", "status", "error", *swept}
    metric_cols = [
        k for k in cols if k not in fixed and any(r[k] is not None for r in rows) and all(
            r[k] is None or (isinstance(r[k], int | float) and not isinstance(r[k], bool))
            for r in rows
        )
    ]  # fmt: skip
    return rows, swept, metric_cols


def _fmt_cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v).replace("|", "\\|").replace("\n", " ")


def write_report(run_dir: str | Path) -> tuple[list[dict[str, Any]], Path]:
    """``fxspace report DIR``: `collect` the runs under ``run_dir`` and write
    ``DIR/report/runs.csv``, ``runs.md`` and one figure per (metric, swept key) — the
    metric against that key, one line per combination of the other swept keys, the best
    run marked (the highest ``r`` / score / accuracy, else the lowest value; constant
    metrics and timings get no figure) — then print the table. Returns (rows, report folder)."""
    import csv
    import io

    rows, swept, metrics = _collect(run_dir)
    out = Path(run_dir) / "report"
    if not rows:
        raise FileNotFoundError(
            f"no runs under {run_dir} (no folder holds status.json or metrics.json); "
            "pass the --out folder of a run or sweep"
        )
    cols = list(rows[0])
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if v is None else v for k, v in r.items()})
    write_text_atomic(out / "runs.csv", buf.getvalue())
    md = "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n"
    md += "".join("| " + " | ".join(_fmt_cell(r[k]) for k in cols) + " |\n" for r in rows)
    write_text_atomic(out / "runs.md", md)
    print(md, end="")
    _report_figures(rows, swept, metrics, out)
    return rows, out


def _is_bookkeeping(metric: str) -> bool:
    last = metric.rsplit(".", 1)[-1]
    return metric.startswith("timings.") or last.endswith("_s") or last in ("index", "seed")


def _higher_is_better(metric: str) -> bool:
    """The best run of a metric: the highest for a correlation / score / accuracy
    (``r``, ``r_*``, ``*score*``, ``*accuracy*``), else the lowest (errors, costs)."""
    last = metric.rsplit(".", 1)[-1]
    return last == "r" or last.startswith("r_") or "score" in last or "accuracy" in last


def _report_figures(
    rows: list[dict[str, Any]], swept: list[str], metrics: list[str], out: Path
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "complete"]
    files = []
    for m in metrics:
        vals = [r for r in ok if isinstance(r[m], int | float) and np.isfinite(r[m])]
        if len({r[m] for r in vals}) < 2 or _is_bookkeeping(m):
            continue  # a constant, a timing or an index: nothing to compare
        up = _higher_is_better(m)
        best = (max if up else min)(vals, key=lambda r: r[m])
        for x in swept:
            others = [k for k in swept if k != x]
            fig, ax = plt.subplots(figsize=(5, 3.5))
            groups: dict[tuple, list] = {}
            for r in vals:
                groups.setdefault(tuple(r[k] for k in others), []).append(r)
            numeric = all(isinstance(r[x], int | float) for r in vals)
            cats = sorted({str(r[x]) for r in vals})
            for g, rs in sorted(groups.items(), key=lambda t: str(t[0])):
                rs = sorted(rs, key=lambda r: r[x] if numeric else str(r[x]))
                xs = [r[x] if numeric else cats.index(str(r[x])) for r in rs]
                lab = ", ".join(f"{k}={v}" for k, v in zip(others, g, strict=True)) or None
                ax.plot(xs, [r[m] for r in rs], "o-", label=lab)
            bx = best[x] if numeric else cats.index(str(best[x]))
            tag = f"best ({'max' if up else 'min'}: {best['run']})"
            ax.plot([bx], [best[m]], "*", ms=16, color="crimson", label=tag)
            if not numeric:
                ax.set_xticks(range(len(cats)), cats, rotation=30, ha="right", fontsize=7)
            ax.set_xlabel(x)
            ax.set_ylabel(m)
            ax.set_title(f"{m} vs {x}", fontsize=9)
            ax.legend(fontsize=6)
            safe = f"{m}_vs_{x}".replace("/", "-")[:120]
            files.append(save_figure_atomic(fig, out / f"{safe}.png"))
    return files


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
) -> Path:
    """Write a benchmark's comparisons to ``root/bench/NAME.json`` (``root``: ``$FXSPACE_RUNS``
    or ``runs``) with the machine it ran on, for the docs' benchmark page (`fxspace docs`).

    Each row is one comparison, `BENCH_FIELDS`: ``case`` (a label), ``size`` (a number to
    plot against, or ``None``), ``ours`` / ``peer`` (what was timed), ``ours_s`` /
    ``peer_s`` (median seconds) and ``ratio`` (``peer_s / ours_s``, filled in when left out).
    """
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
    record = {"name": name, "title": title, "command": command.strip(), "machine": machine(),
              "rows": out}  # fmt: skip
    return write_json_atomic(root / "bench" / f"{name}.json", to_jsonable(record))
