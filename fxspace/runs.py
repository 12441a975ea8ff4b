"""Run folders: config + seed + versions beside the results, every write atomic.

A run folder holds ``config.toml`` (the resolved config), ``meta.json`` (seed,
versions, git SHA, platform, device), ``metrics.json`` and figures (PNG). Files are
written to a temporary name in the same folder and renamed into place, so an
interrupted run never leaves a half-written file; ``metrics.json`` is written last
and marks the run complete. ``cached`` stores intermediate results so an
interrupted sweep resumes where it stopped; the cache belongs to one *run key* — a hash
of the resolved config, the data (file digests) and the code (:func:`run_key`) — and is
cleared when the key changes, so a changed config, data file or code never reuses it.
``status.json`` says ``running``, ``complete``, ``failed`` (with the error) or
``interrupted``. Files are readable by the group (never 0600).
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
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "write_bytes_atomic",
    "write_text_atomic",
    "write_json_atomic",
    "save_figure_atomic",
    "save_npz_atomic",
    "versions",
    "git_sha",
    "write_meta",
    "cached",
    "to_jsonable",
    "code_digest",
    "file_digest",
    "run_key",
    "write_status",
    "read_status",
    "reset_cache",
]

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
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
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
    return p


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
    """Write ``status.json`` (``running`` / ``complete`` / ``failed`` / ``interrupted``)."""
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
    ``force``). Returns whether an existing cache was cleared."""
    import shutil

    d = Path(run_dir) / "cache"
    kp = d / "KEY"
    old = kp.read_text().strip() if kp.is_file() else None
    cleared = False
    if d.exists() and (force or old != key):
        shutil.rmtree(d)
        cleared = True
    write_text_atomic(kp, key + "\n")
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
    return value


def cached_arrays(
    run_dir: str | Path, name: str, compute: Callable[[], dict[str, Any]]
) -> dict[str, np.ndarray]:
    """A costly pipeline stage, stored once as ``run_dir/cache/NAME.npz`` (atomically).

    ``compute()`` returns a flat ``{name: array-like}``; the stored arrays are returned
    (as NumPy arrays) on this and every later call in the same run folder, so a run
    interrupted after this stage resumes without recomputing it. The cache folder is
    bound to the run's content key (config + data + code, see :func:`reset_cache`), so a
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
    return value
