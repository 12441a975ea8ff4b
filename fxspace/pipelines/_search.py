"""``[search]``: configurations drawn at random or by a sequential model-based search
(Optuna), each one a run folder like a sweep's, for a metric to minimise or maximise.

```toml
[search]
method = "tpe"            # "tpe" (Optuna's Tree-structured Parzen Estimator) or "random"
trials = 12               # configurations in all (over every worker)
metric = "r"              # a key of metrics.json (a dotted path reaches into tables)
direction = "maximize"    # or "minimize"
seed = 0

[search.space]            # the keys drawn, dotted for a key inside a table
"graph.num_thresholds" = { low = 3, high = 8 }        # integers: both bounds integers
"hierarchy.m" = { low = 1.5, high = 3.0, log = true } # floats (log scale optional)
dim = [2, 3]                                          # a list: one of these values
```

The study lives in SQLite beside the runs (``OUT/search.db``, one search per folder). The
command prepares it once, before any worker starts (`prepare_search`): it creates the
study, checks that ``direction`` and ``metric`` are those the study was started with,
marks trials whose process is gone (Ctrl-C, a killed worker) as failed, queues every
failed trial again (in its own folder, which resumes from its cached stages: a run that
had finished only has its metric read again) and queues the start design — the first
configurations (all of them for ``method = "random"``, the first 10 for TPE), drawn
from ``seed`` without repeats. Then every worker of ``fxspace sweep CONFIG --workers
N`` (processes here, or a Dask cluster with ``--scheduler``, sharing the folder) asks the
study for the next configuration under a file lock (``OUT/.search-lock``) and tells it
the result; a configuration the sampler draws again is replaced by one not yet tried.
Configuration ``k`` runs in ``OUT/trial_KKKK`` exactly as ``fxspace run`` would run it;
rerunning the command continues the study up to ``trials`` (a finished trial is never
rerun). A trial whose run fails, or whose metric is missing or not finite, is told to
the study as failed with the reason, the search goes on, and the command exits non-zero.
``--force`` starts a fresh study (the old one is deleted from ``search.db`` and the files
fxspace wrote in its trial folders removed). ``fxspace report OUT`` compares the trials.
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import random
import socket
import sys
import time
import traceback
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

from fxspace.config import ConfigError
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.runs import pid_alive

__all__ = [
    "SEARCH_METHODS",
    "check_search",
    "search_worker",
    "metric_value",
    "search_study",
    "prepare_search",
    "search_outcomes",
    "named_output",
]

SEARCH_METHODS = ("tpe", "random")
_KEYS = {"method", "trials", "metric", "direction", "seed", "space"}
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


def check_search(table: Any) -> dict:
    """The ``[search]`` table checked (every problem named with its key); returns it with
    defaults filled in."""
    if not isinstance(table, dict):
        raise ConfigError("[search] must be a table (method, trials, metric, direction, space)")
    extra = set(table) - _KEYS
    if extra:
        raise ConfigError(f"[search] has unknown keys {sorted(extra)}; allowed: {sorted(_KEYS)}")
    s = {"method": "tpe", "direction": "minimize", "seed": 0, **table}
    if s["method"] not in SEARCH_METHODS:
        raise ConfigError(f"search.method must be one of {SEARCH_METHODS}, got {s['method']!r}")
    if s["direction"] not in ("minimize", "maximize"):
        raise ConfigError(
            f"search.direction must be 'minimize' or 'maximize', got {s['direction']!r}"
        )
    t = s.get("trials")
    if isinstance(t, bool) or not isinstance(t, int) or t < 1:
        raise ConfigError(f"search.trials must be an integer >= 1, got {t!r}")
    sd = s.get("seed")
    if isinstance(sd, bool) or not isinstance(sd, int) or not 0 <= sd < 2**31:
        raise ConfigError(f"search.seed must be an integer in [0, 2**31), got {sd!r}")
    if not isinstance(s.get("metric"), str) or not s["metric"]:
        raise ConfigError('search.metric must name a key of metrics.json (e.g. metric = "r")')
    space = s.get("space")
    if not isinstance(space, dict) or not space:
        raise ConfigError("[search.space] must give at least one key to draw")
    for k, v in space.items():
        _distribution(k, v)
    return s


def _distribution(key: str, spec: Any):
    """The Optuna distribution of one ``[search.space]`` entry (checked)."""
    import optuna.distributions as od

    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"search.space.{key}: an empty list of choices")
        return od.CategoricalDistribution(spec)
    if not isinstance(spec, dict) or not {"low", "high"} <= set(spec):
        raise ConfigError(
            f"search.space.{key} must be a list of choices or {{low = …, high = …}}, got {spec!r}"
        )
    lo, hi, log = spec["low"], spec["high"], bool(spec.get("log", False))
    if set(spec) - {"low", "high", "log"}:
        raise ConfigError(f"search.space.{key}: only low, high and log are allowed")
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in (lo, hi)):
        raise ConfigError(f"search.space.{key}: low and high must be numbers")
    if not lo < hi or (log and lo <= 0):
        raise ConfigError(f"search.space.{key}: need low < high (and low > 0 with log = true)")
    if isinstance(lo, int) and isinstance(hi, int):
        return od.IntDistribution(lo, hi, log=log)
    return od.FloatDistribution(float(lo), float(hi), log=log)


def _set_dotted(raw: dict, key: str, value: Any) -> None:
    node = raw
    *path, last = key.split(".")
    for p in path:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"search.space.{key}: {p!r} is not a table of the config")
    node[last] = value


def metric_value(metrics: dict, name: str) -> float:
    """``metrics[name]`` (a dotted path reaches into tables) as a finite float, or a
    `ConfigError` saying what was found."""
    node: Any = metrics
    for p in name.split("."):
        if not isinstance(node, dict) or p not in node:
            raise ConfigError(f"metrics.json has no {name!r} (search.metric); keys: "
                              f"{sorted(metrics)[:12]} …")  # fmt: skip
        node = node[p]
    if isinstance(node, bool) or not isinstance(node, int | float) or not math.isfinite(node):
        raise ConfigError(f"metric {name!r} is {node!r}, not a finite number")
    return float(node)


# ------------------------------------------------------------------ worker output


class _Prefixed(io.TextIOBase):
    """A text stream that writes each whole line to ``stream`` behind ``prefix``; a line
    redrawn with ``\r`` (a progress bar) keeps only its last state, a blank one is
    dropped, so N workers' bars never interleave into garbage."""

    def __init__(self, stream: Any, prefix: str) -> None:
        self._stream, self._prefix, self._buf = stream, prefix, ""

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        self._buf += s
        *lines, rest = self._buf.split("\n")
        self._buf = rest.rsplit("\r", 1)[-1]
        lines = [ln.rsplit("\r", 1)[-1] for ln in lines]
        for ln in lines:
            if ln.strip():
                self._stream.write(f"{self._prefix}{ln}\n")
        if lines:
            self._stream.flush()
        return len(s)

    def flush(self) -> None:
        self._stream.flush()

    def finish(self) -> None:
        if self._buf.strip():
            self._stream.write(f"{self._prefix}{self._buf}\n")
            self._buf = ""
        self._stream.flush()


@contextmanager
def named_output(name: str | None):
    """Within this block, every line printed to stdout or stderr starts with ``[name]``
    (a worker's lines among other workers'; progress bars reduced to nothing, the
    sweep's own progress lines say how far it is); ``None``: unchanged."""
    if name is None:
        yield
        return
    out = _Prefixed(sys.stdout, f"[{name}] ")
    err = _Prefixed(sys.stderr, f"[{name}] ")
    try:
        with redirect_stdout(out), redirect_stderr(err):
            yield
    finally:
        out.finish()
        err.finish()


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


def _params_key(params: dict) -> tuple:
    return tuple(sorted((k, repr(v)) for k, v in params.items()))


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


def _space_size(space: dict) -> float:
    import optuna.distributions as od

    n = 1.0
    for d in space.values():
        if isinstance(d, od.CategoricalDistribution):
            n *= len(d.choices)
        elif isinstance(d, od.IntDistribution):
            n *= (d.high - d.low) // d.step + 1
        else:
            return math.inf
    return n


def _draw(space: dict, rng: random.Random) -> dict:
    import optuna.distributions as od

    p: dict[str, Any] = {}
    for k, d in space.items():
        if isinstance(d, od.CategoricalDistribution):
            p[k] = rng.choice(list(d.choices))
        elif isinstance(d, od.IntDistribution):
            if d.log:
                v = round(math.exp(rng.uniform(math.log(d.low), math.log(d.high))))
                p[k] = int(min(max(v, d.low), d.high))
            else:
                p[k] = rng.randrange(d.low, d.high + 1, d.step)
        elif d.log:
            p[k] = math.exp(rng.uniform(math.log(d.low), math.log(d.high)))
        else:
            p[k] = rng.uniform(d.low, d.high)
    return p


def _untried(space: dict, taken: set, rng: random.Random, n: int = 1) -> list[dict]:
    """Up to ``n`` configurations of ``space`` whose keys are not in ``taken`` (none when
    every point of a finite space is taken)."""
    import itertools

    import optuna.distributions as od

    size = _space_size(space)
    if size <= 20000:  # finite and small: choose among the points left
        axes = []
        for k, d in space.items():
            vals = d.choices if isinstance(d, od.CategoricalDistribution) else range(
                d.low, d.high + 1, d.step)  # fmt: skip
            axes.append([(k, v) for v in vals])
        left = [dict(c) for c in itertools.product(*axes) if _params_key(dict(c)) not in taken]
        rng.shuffle(left)
        return left[:n]
    got = []
    for _ in range(200 * n):
        p = _draw(space, rng)
        key = _params_key(p)
        if key not in taken:
            taken = taken | {key}
            got.append(p)
            if len(got) == n:
                break
    return got


# ------------------------------------------------------------------ preparing


def _trial_folders(out: Path) -> list[Path]:
    import re

    return sorted(
        d for d in out.glob("trial_*") if re.fullmatch(r"trial_\d{4,}", d.name)
        and ((d / ".fxspace-manifest").is_file() or (d / "status.json").is_file())
    )  # fmt: skip


def _clean_trials(out: Path) -> list[str]:
    """``--force``: remove the files fxspace wrote in ``out``'s trial folders (their
    manifests); a folder left empty goes too, a user's file stays."""
    from fxspace.runs import clean_run

    gone = []
    for d in _trial_folders(out):
        clean_run(d)
        gone.append(d.name)
        try:
            d.rmdir()
        except OSError:
            pass  # it still holds a file fxspace did not write
    return gone


def _summary_of(search: dict) -> dict:
    space = json.dumps(search["space"], sort_keys=True)
    return {"metric": search["metric"], "direction": search["direction"],
            "method": search["method"], "space": space}  # fmt: skip


def prepare_search(config: str | Path, out: str | Path, search: dict, force: bool = False) -> int:
    """Prepare the search's study once, before any worker starts: create it in
    ``out/search.db`` (or, with ``force``, delete the studies there and the files
    fxspace wrote in their trial folders first); refuse another search's study or trial
    folders, a changed ``direction`` and a changed ``metric`` once a trial completed (each
    naming the fix); fail the trials whose process is gone; queue every failed
    configuration again and the start design. Returns how many trials are left to run."""
    import optuna
    from optuna.trial import TrialState

    out, name = Path(out), Path(config).stem
    out.mkdir(parents=True, exist_ok=True)
    db = out / "search.db"
    fresh = "pass --force to start a fresh study (it deletes the old one), or choose another --out"
    with _study_lock(out):
        storage = _storage(out)
        with _db_errors(db):
            names = [s.study_name for s in storage.get_all_studies()]
            if force and (names or _trial_folders(out)):
                for n in names:
                    optuna.delete_study(study_name=n, storage=storage)
                gone = _clean_trials(out)
                print(f"[search] --force: a fresh study; deleted {names or 'no study'} from "
                      f"{db} and the files fxspace wrote in {len(gone)} trial folders",
                      flush=True)  # fmt: skip
                names = []
            others = [n for n in names if n != name]
            if others:
                raise ConfigError(
                    f"{db} holds the study of another search ({', '.join(map(repr, others))}, "
                    f"its runs in {out}/trial_*); this config's study is {name!r}: one "
                    f"search per folder; {fresh}"
                )
            if name not in names:
                orphans = [d.name for d in _trial_folders(out)]
                if orphans:
                    raise ConfigError(
                        f"{out} holds trial folders ({', '.join(orphans[:3])}"
                        f"{' …' if len(orphans) > 3 else ''}) that no study in {db} records "
                        f"(a deleted search.db?); {fresh}"
                    )
            study = optuna.create_study(
                study_name=name, storage=storage, direction=search["direction"],
                load_if_exists=True,
            )  # fmt: skip
            _check_settings(study, search, db, fresh)
            queued, notes = _recover(study, storage, out, retry_failed=True)
            for n in notes:
                print(f"[search] {n}", flush=True)
            if queued:
                print(f"[search] {queued} failed or interrupted trial(s) queued again (each "
                      "in its own folder; a finished run only has its metric read)",
                      flush=True)  # fmt: skip
            trials = study.get_trials(deepcopy=False)
            latest = _latest(trials)
            _design(study, search, latest, trials)
            trials = study.get_trials(deepcopy=False)
            latest = _latest(trials)
            retries = sum(t.state == TrialState.WAITING and _SLOT in t.user_attrs for t in trials)
            running = sum(t.state == TrialState.RUNNING for t in latest.values())
            if running:
                print(f"[search] {running} trial(s) running in another process", flush=True)
            return max(search["trials"] - len(latest), 0) + retries


def _check_settings(study, search: dict, db: Path, fresh: str) -> None:
    from optuna.trial import TrialState

    now = _summary_of(search)
    was_dir = study.direction.name.lower()
    if was_dir != search["direction"]:
        raise ConfigError(
            f"{db}: the study {study.study_name!r} was started to {was_dir} "
            f"search.metric; the config now says direction = {search['direction']!r}: set "
            f"direction = {was_dir!r} back, or {fresh}"
        )
    old = study.user_attrs.get(_SETTINGS)
    if old is None:
        study.set_user_attr(_SETTINGS, now)
        return
    if old.get("metric") != now["metric"]:
        done = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))]
        if done:
            raise ConfigError(
                f"{db}: the study {study.study_name!r} ranks its {len(done)} completed "
                f"trials by metric {old.get('metric')!r}; the config now says "
                f"metric = {now['metric']!r}: set it back, or {fresh}"
            )
        print(f"[search] search.metric is now {now['metric']!r} (was {old.get('metric')!r}, "
              "which no trial completed): the failed trials are read again",
              flush=True)  # fmt: skip
    for key in ("method", "space"):
        if old.get(key) != now[key]:
            print(f"[search] note: search.{key} changed since the study began; the earlier "
                  "trials stay in the study and inform the sampler", flush=True)  # fmt: skip
    study.set_user_attr(_SETTINGS, now)


def _design(study, search: dict, latest: dict, trials) -> None:
    """Queue the start design once: the first configurations drawn from ``seed``
    without repeats (all ``trials`` for random search, the first 10 for TPE)."""
    from optuna.trial import TrialState

    want = search["trials"] if search["method"] == "random" else _TPE_STARTUP
    want = min(want, search["trials"])
    have = int(study.user_attrs.get(_DESIGN, 0))
    if have == 0 and latest:  # a study from before the design: its draws count
        have = len(latest)
    n = min(want - have, search["trials"] - len(latest))
    if n <= 0:
        return
    space = {k: _distribution(k, v) for k, v in search["space"].items()}
    taken = {_params_key(t.params) for t in latest.values()}
    taken |= {_params_key(_queued_params(t)) for t in trials if t.state == TrialState.WAITING}
    pts = _untried(space, taken, random.Random(int(search["seed"])), n)
    for p in pts:
        study.enqueue_trial(p)
    study.set_user_attr(_DESIGN, have + len(pts))


# ------------------------------------------------------------------ the workers


def _next_trial(study, storage, search: dict, space: dict, out: Path, worker: int):
    """Under the search's lock: the next trial to run and its configuration index, or
    ``(None, why)`` when the study holds its trials (or the space has no point left)."""
    from optuna.trial import TrialState

    _recover(study, storage, out, retry_failed=False)
    for _ in range(100):
        trials = study.get_trials(deepcopy=False)
        latest = _latest(trials)
        retry_queued = any(t.state == TrialState.WAITING and _SLOT in t.user_attrs
                           for t in trials)  # fmt: skip
        if len(latest) >= search["trials"] and not retry_queued:
            return None, "done"
        trial = study.ask(space)
        k = trial.user_attrs.get(_SLOT)
        if k is None:
            if len(latest) >= search["trials"]:
                trial.set_user_attr(_SKIP, "not needed: the study holds its trials")
                study.tell(trial, state=TrialState.FAIL)
                continue
            taken = {_params_key(t.params): _slot_name(s) for s, t in latest.items()}
            taken |= {_params_key(_queued_params(t)): "a queued configuration" for t in trials
                      if t.state == TrialState.WAITING and _SLOT not in t.user_attrs
                      and t.number != trial.number}  # fmt: skip
            twin = taken.get(_params_key(trial.params))
            if twin is not None:
                trial.set_user_attr(_SKIP, f"a repeat of {twin}")
                study.tell(trial, state=TrialState.FAIL)
                rng = random.Random(int(search["seed"]) * 1_000_003 + len(trials) + worker)
                new = _untried(space, set(taken), rng)
                if not new:
                    return None, "exhausted"
                study.enqueue_trial(new[0])
                continue
            k = max(latest, default=-1) + 1
            trial.set_user_attr(_SLOT, k)
        trial.set_user_attr(_HOST, socket.gethostname())
        trial.set_user_attr(_PID, os.getpid())
        return trial, int(k)
    return None, "no new configuration after 100 draws"


def search_worker(config: str, out: str, worker: int = 0, force: bool = False,
                  named: bool = False) -> dict:  # fmt: skip
    """One worker's loop: take the next trial (under the search's lock), run its
    configuration in its trial folder, tell the study the metric; until the study holds
    ``trials`` configurations. Ctrl-C marks the running trial failed (interrupted: the
    next command runs it again) before it stops. ``named``: each trial's output lines
    start with its folder's name. Returns ``{"run_dir", "status", "error", "trials":
    [...]}`` (one entry per trial run here). ``force`` is `prepare_search`'s business
    (kept for callers)."""
    from optuna.trial import TrialState

    from fxspace.config import load_toml
    from fxspace.pipelines import run_dict

    raw = load_toml(config)
    search = check_search(raw.get("search"))
    base = {k: v for k, v in raw.items() if k not in ("search", "sweep")}
    space = {k: _distribution(k, v) for k, v in search["space"].items()}
    outp = Path(out)
    name = Path(config).stem
    storage = _storage(outp)
    import optuna

    with _db_errors(outp / "search.db"):
        study = optuna.load_study(study_name=name, storage=storage,
                                  sampler=_sampler(search, worker))  # fmt: skip
    done: list[dict] = []
    why = "done"
    while True:
        with _study_lock(outp), _db_errors(outp / "search.db"):
            trial, k = _next_trial(study, storage, search, space, outp, worker)
        if trial is None:
            why = k
            break
        cfg = copy.deepcopy(base)
        for key, v in trial.params.items():
            _set_dotted(cfg, key, v)
        run_dir = outp / _slot_name(k)
        retry = trial.user_attrs.get(_RETRY_OF)
        entry = {"trial": k, "run_dir": str(run_dir), "params": trial.params,
                 "retry_of": retry}  # fmt: skip
        try:
            base_dir = Path(config).resolve().parent
            d = _finished(cfg, run_dir) if retry is not None else None
            if d is not None:
                print(f"[search] {run_dir.name}: its run had finished; its metric is read "
                      "again", flush=True)  # fmt: skip
            else:
                with named_output(run_dir.name if named else None):
                    (d,) = run_dict(cfg, run_dir, base_dir=base_dir)
            value = metric_value(json.loads((d / "metrics.json").read_text()), search["metric"])
            study.tell(trial, value)
            entry.update(status="complete", value=value)
        except BaseException as e:  # noqa: BLE001 - the trial fails, the search goes on
            err = f"{type(e).__name__}: {e}".strip()
            stop = not isinstance(e, Exception)  # Ctrl-C, SystemExit: told, then stop
            if stop:
                err = "interrupted (Ctrl-C); the next fxspace sweep runs it again"
                trial.set_user_attr(_INTERRUPTED, True)
            trial.set_user_attr(_ERROR, err[:2000])
            study.tell(trial, state=TrialState.FAIL)
            entry.update(status="failed", error=err, traceback=traceback.format_exc(3))
            if stop:
                print(f"[search] {run_dir.name}: {err}", flush=True)
                raise
        again = ", run again" if retry is not None else ""
        what = (f"{search['metric']} = {entry['value']:.6g}" if entry["status"] == "complete"
                else entry["error"])  # fmt: skip
        print(f"[search] {run_dir.name} (worker {worker}{again}): {entry['status']}, {what} "
              f"{trial.params}", flush=True)  # fmt: skip
        done.append(entry)
    if why == "exhausted":
        print(f"[search] worker {worker}: every configuration of [search.space] has been "
              "tried; the search ends here", flush=True)  # fmt: skip
    elif why != "done":
        print(f"[search] worker {worker} stops: {why}", flush=True)
    failed = [t for t in done if t["status"] == "failed"]
    return {"run_dir": f"{out}#worker{worker}", "name": f"search worker {worker}",
            "status": "failed" if failed else "complete",
            "error": failed[0]["error"] if failed else None, "trials": done}  # fmt: skip


def _finished(cfg: dict, run_dir: Path) -> Path | None:
    """``run_dir`` when it holds the finished run of exactly ``cfg`` (a failed trial
    whose run had completed, say under a misspelt metric: only its metric is read again,
    even where fxspace's code changed since), else ``None``."""
    from fxspace.pipelines import resolve_config
    from fxspace.runs import read_status

    if read_status(run_dir).get("status") != "complete":
        return None
    try:
        (spec,) = resolve_config(cfg, run_dir)
        same = (run_dir / "config.toml").read_text() == spec.text
    except (OSError, ValueError):
        return None
    return run_dir if same and (run_dir / "metrics.json").is_file() else None


def search_outcomes(
    config: str | Path, out: str | Path, search: dict, got: list[dict]
) -> list[dict]:
    """One outcome per configuration of the study (its latest trial, in order): complete
    with its value, failed with the reason, interrupted, or running in another process;
    plus any worker that was lost before it ran a trial. Prints the study's tally."""
    from optuna.trial import TrialState

    out = Path(out)
    study = search_study(out, Path(config).stem, search)
    with _db_errors(out / "search.db"):
        latest = _latest(study.get_trials(deepcopy=False))
    res = []
    for k, t in sorted(latest.items()):
        r = {"trial": k, "run_dir": str(out / _slot_name(k)), "params": dict(t.params),
             "error": None}  # fmt: skip
        if t.state == TrialState.COMPLETE:
            r.update(status="complete", value=t.value)
        elif t.state == TrialState.RUNNING:
            r.update(status="running", error=f"still running in pid {t.user_attrs.get(_PID)} on "
                     f"{t.user_attrs.get(_HOST)} (another fxspace sweep of this search?); "
                     "rerun once it ends")  # fmt: skip
        elif t.state == TrialState.WAITING:
            r.update(status="failed", params=_queued_params(t),
                     error="queued again but not run yet; rerun the command")  # fmt: skip
        else:
            r.update(status="failed", error=t.user_attrs.get(_ERROR) or "failed (no reason kept)")
        res.append(r)
    lost = [g for g in got if g.get("status") == "failed" and not g.get("trials")]
    res += [{**g, "status": "failed"} for g in lost]
    n_ok = sum(r["status"] == "complete" for r in res)
    n_int = sum(r["status"] == "failed" and "interrupted" in str(r["error"]) for r in res)
    n_run = sum(r["status"] == "running" for r in res)
    ran = sum(len(g.get("trials", ())) for g in got)
    best = ""
    ok = [r for r in res if r["status"] == "complete"]
    if ok:
        pick = (max if search["direction"] == "maximize" else min)(ok, key=lambda r: r["value"])
        best = f"; best {search['metric']} = {pick['value']:.6g} in {Path(pick['run_dir']).name}"
    short = search["trials"] - len(latest)
    tally = f"{n_ok} complete, {len(res) - n_ok - n_int - n_run} failed"
    tally += f", {n_int} interrupted" if n_int else ""
    tally += f", {n_run} running elsewhere" if n_run else ""
    tally += f", {short} never drawn" if short > 0 else ""
    print(f"[search] study {study.study_name!r}: {tally} of {search['trials']} trials ({ran} "
          f"run by this command){best}", flush=True)  # fmt: skip
    return res
