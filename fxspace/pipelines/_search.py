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
import json
import os
import random
import re
import socket
import traceback
from pathlib import Path

from fxspace.config import ConfigError, load_toml
from fxspace.pipelines._output import named_output
from fxspace.pipelines._planner import resolve_config
from fxspace.pipelines._runner import run_dict
from fxspace.pipelines._search_space import (
    SEARCH_METHODS,
    _distribution,
    _params_key,
    _set_dotted,
    _untried,
    check_search,
    metric_value,
)
from fxspace.pipelines._study import (
    _DESIGN,
    _ERROR,
    _HOST,
    _INTERRUPTED,
    _PID,
    _RETRY_OF,
    _SETTINGS,
    _SKIP,
    _SLOT,
    _TPE_STARTUP,
    _db_errors,
    _latest,
    _queued_params,
    _recover,
    _sampler,
    _slot_name,
    _storage,
    _study_lock,
    search_study,
)
from fxspace.runs import clean_run, read_status

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

# ------------------------------------------------------------------ preparing


def _trial_folders(out: Path) -> list[Path]:
    return sorted(
        d for d in out.glob("trial_*") if re.fullmatch(r"trial_\d{4,}", d.name)
        and ((d / ".fxspace-manifest").is_file() or (d / "status.json").is_file())
    )  # fmt: skip


def _clean_trials(out: Path) -> list[str]:
    """``--force``: remove the files fxspace wrote in ``out``'s trial folders (their
    manifests); a folder left empty goes too, a user's file stays."""
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
