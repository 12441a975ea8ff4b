"""``[search]``: configurations drawn at random or by a sequential model-based search
(Optuna), each one a run folder like a sweep's, for a metric to minimise or maximise.

```toml
[search]
method = "tpe"            # "tpe" (Optuna's Tree-structured Parzen Estimator) or "random"
trials = 12               # runs in all (over every worker)
metric = "r"              # a key of metrics.json (a dotted path reaches into tables)
direction = "maximize"    # or "minimize"
seed = 0

[search.space]            # the keys drawn, dotted for a key inside a table
"graph.num_thresholds" = { low = 3, high = 8 }        # integers: both bounds integers
"hierarchy.m" = { low = 1.5, high = 3.0, log = true } # floats (log scale optional)
dim = [2, 3]                                          # a list: one of these values
```

The study lives in SQLite beside the runs (``OUT/search.db``), so every worker of
``fxspace sweep CONFIG --workers N`` (processes here, or a Dask cluster with
``--scheduler``, sharing the folder) asks it for the next configuration and tells it the
result; trial ``n`` runs in ``OUT/trial_NNNN`` exactly as ``fxspace run`` would run that
configuration (a finished trial is never rerun: rerunning the command continues the
study up to ``trials``). ``fxspace report OUT`` compares the trials like a sweep's runs.
A trial whose run fails, or whose metric is missing or not finite, is told to the study
as failed with the reason, and the search goes on.
"""

from __future__ import annotations

import copy
import json
import math
import traceback
from pathlib import Path
from typing import Any

from fxspace.config import ConfigError

__all__ = ["SEARCH_METHODS", "check_search", "search_worker", "metric_value", "search_study"]

SEARCH_METHODS = ("tpe", "random")
_KEYS = {"method", "trials", "metric", "direction", "seed", "space"}


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


def search_study(out: Path, name: str, search: dict, worker: int = 0):
    """The Optuna study of this search (SQLite ``out/search.db``, shared by workers)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out.mkdir(parents=True, exist_ok=True)
    seed = int(search["seed"]) + 1000 * int(worker)  # workers draw different start points
    sampler = (
        optuna.samplers.TPESampler(seed=seed)
        if search["method"] == "tpe"
        else optuna.samplers.RandomSampler(seed=seed)
    )
    return optuna.create_study(
        study_name=name, storage=f"sqlite:///{(out / 'search.db').resolve()}",
        sampler=sampler, direction=search["direction"], load_if_exists=True,
    )  # fmt: skip


def search_worker(config: str, out: str, worker: int = 0, force: bool = False) -> dict:
    """One worker's loop: ask the study for a configuration, run it in its trial folder,
    tell the study the metric; until the study holds ``trials`` trials. Returns
    ``{"run_dir", "status", "error", "trials": [...]}`` (one entry per trial run here)."""
    import optuna
    from optuna.trial import TrialState

    from fxspace.config import load_toml
    from fxspace.pipelines import run_dict

    raw = load_toml(config)
    search = check_search(raw.get("search"))
    base = {k: v for k, v in raw.items() if k not in ("search", "sweep")}
    space = {k: _distribution(k, v) for k, v in search["space"].items()}
    outp = Path(out)
    study = search_study(outp, Path(config).stem, search, worker)
    done: list[dict] = []
    live = (TrialState.COMPLETE, TrialState.RUNNING, TrialState.FAIL)
    while len(study.get_trials(deepcopy=False, states=live)) < search["trials"]:
        trial = study.ask(space)
        if trial.number >= search["trials"]:  # another worker took the last one meanwhile
            study.tell(trial, state=TrialState.PRUNED)
            break
        cfg = copy.deepcopy(base)
        for k, v in trial.params.items():
            _set_dotted(cfg, k, v)
        run_dir = outp / f"trial_{trial.number:04d}"
        entry = {"trial": trial.number, "run_dir": str(run_dir), "params": trial.params}
        try:
            (d,) = run_dict(cfg, run_dir, force=force, base_dir=Path(config).resolve().parent)
            value = metric_value(json.loads((d / "metrics.json").read_text()), search["metric"])
            study.tell(trial, value)
            entry.update(status="complete", value=value)
        except Exception as e:  # noqa: BLE001 - the trial fails, the search goes on
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
            trial_err = f"{type(e).__name__}: {e}"
            entry.update(status="failed", error=trial_err, traceback=traceback.format_exc(3))
        print(f"[search] trial {trial.number}: {entry['status']} "
              f"{entry.get('value', entry.get('error'))} {trial.params}", flush=True)  # fmt: skip
        done.append(entry)
    failed = [t for t in done if t["status"] == "failed"]
    return {"run_dir": f"{out}#worker{worker}", "status": "failed" if failed else "complete",
            "error": failed[0]["error"] if failed else None, "trials": done}  # fmt: skip
