"""The stage cache: a costly stage computed once per run key, resumed after a stop.

``cached`` (JSON) and ``cached_arrays`` (``.npz``) store intermediate results in
``run_dir/cache`` so an interrupted run or sweep resumes where it stopped. The cache
belongs to one *run key* — a hash of the resolved config, the data (file digests) and
the code (`fxspace.runs.run_key`) — and is cleared when the key changes (`reset_cache`),
so a changed config, data file or code never reuses it. Clearing deletes only the cache
files fxspace wrote (the folder's manifest); an entry is served only while it is still
the very file fxspace wrote; a cache folder that cannot be used (a link, a file,
read-only) is skipped with one message, never written through.

The public front is `fxspace.runs`, which re-exports every name here.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fxspace._atomic import (
    OverwriteRefusedError,
    UnsafePathError,
    _Active,
    _check_ours,
    _kind,
    _manifest_entries,
    _rel_inside,
    _unsafe_below,
    manifest_files,
    read_regular,
    record,
    to_jsonable,
    unrecorded,
    write_bytes_atomic,
    write_text_atomic,
)
from fxspace._run_folder import _remove_listed
from fxspace.errors import FxspaceError

__all__ = ["cached", "cached_arrays", "reset_cache"]

# run folders whose cache folder cannot be used (a link, a file, unwritable): their
# stages are computed without a cache (said once, when found)
_NO_CACHE: set[Path] = set()


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
    a member whose CRC-32 or contents do not check out) is recomputed, with a message;
    a cache folder that cannot be written is skipped with a message.

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
    # stored, not deflated: a stage's arrays are mostly float noise (a 2 400-frame space
    # deflates 46 → 20 MB in 1.0 s, written as it is in 0.06 s); each member's CRC-32
    # still finds a damaged file
    np.savez(buf, **value)
    _store(run_dir, p, buf.getvalue())
    return value
