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

This module is the public front; each job has its own private module, and every name
is re-exported here (``from fxspace.runs import …`` keeps working):
``fxspace._atomic`` (atomic writes, safe reads, the manifest: every layer may use them),
``fxspace._run_folder`` (lock, status, meta, clean), ``fxspace._stage_cache`` (`cached`,
`cached_arrays`, `reset_cache`) and ``fxspace._bench_record`` (`write_bench`). The run
key (`run_key`, `code_digest`, `file_digest`) stays here: pipelines read
``fxspace.runs.code_digest`` and tests replace it there, and `run_key` reads it from
this module.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from fxspace._atomic import _ACTIVE as _ACTIVE
from fxspace._atomic import _LISTED as _LISTED
from fxspace._atomic import MANIFEST as MANIFEST
from fxspace._atomic import OverwriteRefusedError as OverwriteRefusedError
from fxspace._atomic import UnsafePathError as UnsafePathError
from fxspace._atomic import _Active as _Active
from fxspace._atomic import _check_ours as _check_ours
from fxspace._atomic import _kind as _kind
from fxspace._atomic import _manifest_entries as _manifest_entries
from fxspace._atomic import _manifest_path as _manifest_path
from fxspace._atomic import _rel_inside as _rel_inside
from fxspace._atomic import _safe_rel as _safe_rel
from fxspace._atomic import _umask as _umask
from fxspace._atomic import _unsafe_below as _unsafe_below
from fxspace._atomic import active_run as active_run
from fxspace._atomic import check_writable as check_writable
from fxspace._atomic import manifest_files as manifest_files
from fxspace._atomic import read_json as read_json
from fxspace._atomic import read_regular as read_regular
from fxspace._atomic import record as record
from fxspace._atomic import save_figure_atomic as save_figure_atomic
from fxspace._atomic import save_npz_atomic as save_npz_atomic
from fxspace._atomic import to_jsonable as to_jsonable
from fxspace._atomic import unrecorded as unrecorded
from fxspace._atomic import write_bytes_atomic as write_bytes_atomic
from fxspace._atomic import write_json_atomic as write_json_atomic
from fxspace._atomic import write_text_atomic as write_text_atomic
from fxspace._bench_record import BENCH_FIELDS as BENCH_FIELDS
from fxspace._bench_record import _is_bench_record as _is_bench_record
from fxspace._bench_record import bench_name_ok as bench_name_ok
from fxspace._bench_record import is_bench_record as is_bench_record
from fxspace._bench_record import machine as machine
from fxspace._bench_record import write_bench as write_bench
from fxspace._run_folder import _PACKAGES as _PACKAGES
from fxspace._run_folder import _USER_STATE as _USER_STATE
from fxspace._run_folder import LOCK as LOCK
from fxspace._run_folder import RunLockedError as RunLockedError
from fxspace._run_folder import _deletion_order as _deletion_order
from fxspace._run_folder import _in_nested_run as _in_nested_run
from fxspace._run_folder import _lock_holder as _lock_holder
from fxspace._run_folder import _remove_listed as _remove_listed
from fxspace._run_folder import _unlink_if_same as _unlink_if_same
from fxspace._run_folder import clean_run as clean_run
from fxspace._run_folder import git_sha as git_sha
from fxspace._run_folder import pid_alive as pid_alive
from fxspace._run_folder import read_status as read_status
from fxspace._run_folder import run_lock as run_lock
from fxspace._run_folder import sweep_threshold as sweep_threshold
from fxspace._run_folder import update_meta as update_meta
from fxspace._run_folder import versions as versions
from fxspace._run_folder import write_meta as write_meta
from fxspace._run_folder import write_status as write_status
from fxspace._stage_cache import _NO_CACHE as _NO_CACHE
from fxspace._stage_cache import _cache_entry as _cache_entry
from fxspace._stage_cache import _cache_unusable as _cache_unusable
from fxspace._stage_cache import _no_cache as _no_cache
from fxspace._stage_cache import _read_key as _read_key
from fxspace._stage_cache import _store as _store
from fxspace._stage_cache import cached as cached
from fxspace._stage_cache import cached_arrays as cached_arrays
from fxspace._stage_cache import reset_cache as reset_cache

__all__ = [
    "sweep_threshold",
    "is_bench_record",
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
