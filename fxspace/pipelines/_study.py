"""A search's Optuna study: the SQLite file beside the runs (checked, locked, loaded with a
worker's sampler) and fxspace's bookkeeping in it (each configuration's trial folder, dead
trials failed and queued again)."""

from __future__ import annotations

import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.runs import pid_alive

# the start design's size for TPE (its default n_startup_trials: random draws before the model)
_TPE_STARTUP = 10
# trial user attributes (fxspace's bookkeeping in the study)
_SLOT = "fxspace_slot"  # the configuration's index k: its folder trial_KKKK
_SKIP = "fxspace_skip"  # a drawn repeat (or an unneeded draw): not a configuration
_ERROR = "fxspace_error"
_INTERRUPTED = "fxspace_interrupted"
_HOST, _PID = "fxspace_host", "fxspace_pid"
_RETRY_OF = "fxspace_retry_of"
# study user attributes
_SETTINGS = "fxspace_search"
_DESIGN = "fxspace_design"
_LOCK_NAME = ".search-lock"


# ------------------------------------------------------------------ the study file


def _slot_name(slot: int) -> str:
    return f"trial_{slot:04d}"


@contextmanager
def _study_lock(out: Path, timeout: float = 300.0):
    """Hold ``out/.search-lock`` (an exclusive ``flock``) while the study is prepared or a
    worker takes its next trial, so two workers or two commands never draw at once."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no flock (Windows): SQLite's own locking only
        yield
        return
    p = out / _LOCK_NAME
    fd = os.open(p, os.O_CREAT | os.O_RDWR, 0o644)
    t0, said = time.monotonic(), False
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                waited = time.monotonic() - t0
                if waited > timeout:
                    raise FxspaceError(
                        f"{p}: another process has held the search's lock for {waited:.0f} s; "
                        "if no fxspace sweep of this search is running, rerun"
                    ) from None
                if waited > 10 and not said:
                    print(f"[search] waiting for {p} (another worker is drawing)", flush=True)
                    said = True
                time.sleep(0.05)
        yield
    finally:
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)


def _check_db(db: Path) -> None:
    """``search.db`` is absent, empty, or an SQLite file holding an Optuna study
    database; anything else is a `CorruptFileError` naming it and the fix (checked
    read-only, before Optuna writes to it)."""
    import sqlite3

    fix = "move it aside (or delete it) and rerun, or choose another --out"
    if not (db.exists() or db.is_symlink()):
        return
    if not db.is_file():
        raise CorruptFileError(f"{db} is not a regular file (a folder, a FIFO or a broken "
                               f"link), so it cannot hold the search's study; {fix}")  # fmt: skip
    if db.stat().st_size == 0:
        return
    try:
        con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True, timeout=30)
        try:
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master")}
        finally:
            con.close()
    except sqlite3.Error as e:
        raise CorruptFileError(f"{db} is not an SQLite database ({e}); {fix}") from None
    if tables and not {"studies", "trials", "alembic_version"} <= tables:
        raise CorruptFileError(f"{db} is an SQLite database but not an Optuna study's (its "
                               f"tables: {sorted(tables)[:6]}); {fix}")  # fmt: skip


@contextmanager
def _db_errors(db: Path):
    """A database error inside this block becomes a `CorruptFileError` naming ``db``."""
    import sqlite3

    try:
        from sqlalchemy.exc import SQLAlchemyError
    except ImportError:  # pragma: no cover - optuna always brings sqlalchemy
        SQLAlchemyError = sqlite3.Error  # noqa: N806
    try:
        yield
    except (SQLAlchemyError, sqlite3.Error) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CorruptFileError(
            f"{db}: the search's study database cannot be used ({first}); move it aside "
            "and rerun (or pass --force for a fresh study), or choose another --out"
        ) from None


def _storage(out: Path):
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    db = out / "search.db"
    _check_db(db)
    with _db_errors(db):
        return optuna.storages.RDBStorage(
            f"sqlite:///{db.resolve()}", engine_kwargs={"connect_args": {"timeout": 60}}
        )


def _sampler(search: dict, worker: int):
    import optuna

    seed = int(search["seed"]) + 1000 * int(worker)  # workers draw different points
    if search["method"] == "tpe":
        return optuna.samplers.TPESampler(seed=seed, n_startup_trials=_TPE_STARTUP,
                                          constant_liar=True)  # fmt: skip
    return optuna.samplers.RandomSampler(seed=seed)


def search_study(out: Path, name: str, search: dict, worker: int = 0):
    """The Optuna study of this search (SQLite ``out/search.db``, shared by workers),
    loaded with worker ``worker``'s sampler; `prepare_search` creates it (once)."""
    import optuna

    out = Path(out)
    storage = _storage(out)
    with _db_errors(out / "search.db"):
        names = [s.study_name for s in storage.get_all_studies()]
        if name not in names:
            raise FxspaceError(f"{out / 'search.db'} holds no study {name!r} (it holds "
                               f"{names}); fxspace sweep CONFIG creates it")  # fmt: skip
        return optuna.load_study(study_name=name, storage=storage,
                                 sampler=_sampler(search, worker))  # fmt: skip


# ------------------------------------------------------------------ bookkeeping


def _slot(t) -> int | None:
    """The configuration index of a trial (``None``: a skipped draw, or a queued start
    point not taken yet). A trial of a study from before slots is its own number."""
    from optuna.trial import TrialState

    if _SKIP in t.user_attrs or t.state == TrialState.PRUNED:
        return None
    if _SLOT in t.user_attrs:
        return int(t.user_attrs[_SLOT])
    if t.state in (TrialState.COMPLETE, TrialState.FAIL, TrialState.RUNNING):
        return t.number
    return None


def _latest(trials) -> dict[int, Any]:
    """Each configuration's latest trial (a retry supersedes the failed one)."""
    got: dict[int, Any] = {}
    for t in sorted(trials, key=lambda t: t.number):
        k = _slot(t)
        if k is not None:
            got[k] = t
    return got


def _queued_params(t) -> dict:
    """The configuration of a queued (WAITING) trial: Optuna keeps it as its fixed params."""
    return dict(t.params or t.system_attrs.get("fixed_params") or {})



def _stale(t, out: Path) -> str | None:
    """Why a RUNNING trial is known to be dead (its process is gone), else ``None``
    (running, or on another host where that cannot be told)."""
    host, pid = t.user_attrs.get(_HOST), t.user_attrs.get(_PID)
    if host is None:  # from before this bookkeeping: dead unless its folder is locked
        k = _slot(t)
        locked = k is not None and (out / _slot_name(k) / ".fxspace-lock").exists()
        return None if locked else "interrupted (no process holds its folder)"
    if host == socket.gethostname() and isinstance(pid, int) and not pid_alive(pid):
        return f"interrupted (its process, pid {pid}, is gone)"
    return None


def _trial_id(storage, study, number: int) -> int:
    sid = storage.get_study_id_from_name(study.study_name)
    return storage.get_trial_id_from_study_id_trial_number(sid, number)


def _fail(study, storage, t, why: str, interrupted: bool = True) -> None:
    """Mark the RUNNING trial ``t`` failed with ``why`` (it is queued again later)."""
    from optuna.trial import TrialState

    tid = _trial_id(storage, study, t.number)
    storage.set_trial_user_attr(tid, _ERROR, why)
    if interrupted:
        storage.set_trial_user_attr(tid, _INTERRUPTED, True)
    storage.set_trial_state_values(tid, TrialState.FAIL)


def _recover(study, storage, out: Path, retry_failed: bool) -> tuple[int, list[str]]:
    """Fail the RUNNING trials whose process is gone, and queue them again; with
    ``retry_failed``, every configuration whose latest trial failed is queued again too.
    Returns (queued, notes)."""
    from optuna.trial import TrialState

    notes, queued = [], 0
    trials = study.get_trials(deepcopy=False)
    for t in trials:
        if t.state == TrialState.RUNNING:
            why = _stale(t, out)
            if why is not None:
                _fail(study, storage, t, why)
                k = _slot(t)
                notes.append(f"{_slot_name(t.number if k is None else k)}: {why}; queued again")
                if not retry_failed:
                    _queue_retry(study, t)
                    queued += 1
    if retry_failed:
        trials = study.get_trials(deepcopy=False)
        for k, t in sorted(_latest(trials).items()):
            if t.state == TrialState.FAIL:
                _queue_retry(study, t, k)
                queued += 1
    return queued, notes


def _queue_retry(study, t, slot: int | None = None) -> None:
    k = _slot(t) if slot is None else slot
    study.enqueue_trial(dict(t.params), user_attrs={_SLOT: k, _RETRY_OF: t.number})
