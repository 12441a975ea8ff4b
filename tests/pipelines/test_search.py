"""Issue 32.4: a ``[search]`` table draws configurations (Optuna, its study in SQLite
beside the runs); each trial is a run folder like a sweep's, the report compares them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fxspace.config import ConfigError, dumps_toml, load_toml

optuna = pytest.importorskip("optuna", reason="optuna not installed (pip install -e '.[search]')")

from fxspace.pipelines._search import check_search, metric_value  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def test_search_table_is_checked_naming_the_key():
    good = {"trials": 3, "metric": "r", "space": {"dim": [2, 3], "a.b": {"low": 1, "high": 4}}}
    s = check_search(good)
    assert s["method"] == "tpe" and s["direction"] == "minimize"
    for bad, msg in [
        ({**good, "method": "grid"}, "search.method"),
        ({**good, "trials": 0}, "search.trials"),
        ({**good, "direction": "up"}, "search.direction"),
        ({**good, "metric": ""}, "search.metric"),
        ({**good, "space": {}}, "search.space"),
        ({**good, "space": {"x": {"low": 3, "high": 1}}}, "search.space.x"),
        ({**good, "space": {"x": {"low": 0, "high": 1.0, "log": True}}}, "search.space.x"),
        ({**good, "space": {"x": []}}, "search.space.x"),
        ({**good, "extra": 1}, "unknown keys"),
    ]:
        with pytest.raises(ConfigError, match=msg):
            check_search(bad)
    assert metric_value({"a": {"b": 2}}, "a.b") == 2.0
    with pytest.raises(ConfigError, match="no 'c'"):
        metric_value({"a": 1}, "c")
    with pytest.raises(ConfigError, match="not a finite number"):
        metric_value({"a": float("nan")}, "a")


def test_search_runs_trials_continues_and_reports_failures(tmp_path):
    from fxspace.pipelines import run_config, run_dict
    from fxspace.pipelines._sweep import sweep_config
    from fxspace.report import collect

    raw = load_toml(ROOT / "configs" / "search_example.toml")
    raw["search"]["trials"] = 3
    cfg = tmp_path / "search.toml"
    cfg.write_text(dumps_toml(raw))
    out = tmp_path / "out"
    res = sweep_config(cfg, out, workers=1, engine="serial")
    assert [r["status"] for r in res] == ["complete"] * 3
    assert (out / "search.db").is_file()
    dirs = sorted(out.glob("trial_*"))
    assert [d.name for d in dirs] == ["trial_0000", "trial_0001", "trial_0002"]
    vals = [json.loads((d / "metrics.json").read_text())["r_at_best"] for d in dirs]
    study = optuna.load_study(study_name="search", storage=f"sqlite:///{out / 'search.db'}")
    assert study.best_value == pytest.approx(max(vals))
    for t, d in zip(study.trials, dirs, strict=True):  # each trial ran its drawn config
        c = load_toml(d / "config.toml")
        assert c["dim"] == t.params["dim"]
        assert c["graph"]["num_thresholds"] == t.params["graph.num_thresholds"]
    # the study holds its trials: nothing is rerun, every trial is reported complete
    assert run_config(cfg, out) == dirs
    assert [t.number for t in study.trials] == [0, 1, 2] and len(collect(out)) == 3
    raw["search"].update(metric="no_such_metric", trials=1)
    cfg.write_text(dumps_toml(raw))
    (bad,) = sweep_config(cfg, tmp_path / "bad", workers=1, engine="serial")
    assert bad["status"] == "failed" and "no_such_metric" in bad["error"]
    assert len(set(tuple(sorted(t.params.items())) for t in study.trials)) == 3  # no repeat
    with pytest.raises(ConfigError, match=r"\[search\]"):
        run_dict(raw, tmp_path / "x")


# ------------------------------------------------------------------ issue 44 item 8


def _toy_search(tmp_path, trials):
    import dataclasses
    import types

    from fxspace.pipelines import register

    @dataclasses.dataclass(frozen=True)
    class Cfg:
        x: int = 0
        y: str = "a"

        def validate(self):
            pass

    mod = types.ModuleType("search_toy")
    mod.Config, mod.STAGES = Cfg, ()
    mod.run = lambda cfg, run_dir, seed: {"score": cfg.x + (cfg.y == "b") / 2}
    register(mod, "search_toy")
    p = tmp_path / "toy.toml"
    p.write_text(
        f'experiment = "search_toy"\n[search]\nmethod = "tpe"\ntrials = {trials}\n'
        'metric = "score"\ndirection = "maximize"\n[search.space]\n'
        'x = { low = 0, high = 1 }\ny = ["a", "b"]\n'
    )
    return p


def test_study_made_once_then_concurrent_workers_draw_no_repeat(tmp_path, monkeypatch):
    """Issue 44.8: the study is created once before any worker starts (workers only load
    it: no schema race, no `table studies already exists`), the start design has no
    repeat, and concurrent workers never draw one configuration twice; on a space of 4
    points, 4 trials are exactly its 4 points."""
    import threading

    from fxspace.pipelines import _REGISTERED
    from fxspace.pipelines._search import prepare_search, search_outcomes, search_worker

    cfg, out = _toy_search(tmp_path, trials=4), tmp_path / "o"
    try:
        made = []
        real = optuna.create_study
        monkeypatch.setattr(optuna, "create_study", lambda **k: made.append(1) or real(**k))
        s = check_search(load_toml(cfg)["search"])
        assert prepare_search(cfg, out, s) == 4 and made == [1]
        got = []
        ts = [threading.Thread(target=lambda i=i: got.append(search_worker(str(cfg), str(out), i)))
              for i in range(2)]  # fmt: skip
        for t in ts:
            t.start()
        for t in ts:
            t.join(120)
        assert made == [1] and len(got) == 2  # the workers loaded the study, never made it
        res = search_outcomes(cfg, out, s, got)
        assert [(r["trial"], r["status"]) for r in res] == [(k, "complete") for k in range(4)]
        pts = {(r["params"]["x"], r["params"]["y"]) for r in res}
        assert pts == {(x, y) for x in range(2) for y in "ab"}  # every point once
        assert sorted(t["trial"] for g in got for t in g["trials"]) == list(range(4))
    finally:
        _REGISTERED.pop("search_toy", None)


@pytest.mark.slow
def test_search_example_with_two_workers(tmp_path):
    """Issue 44.8 as reported: `fxspace sweep configs/search_example.toml --workers 2`
    prints no database error, runs 6 distinct configurations, and every line a worker
    prints names its run."""
    import os
    import re
    import subprocess
    import sys

    out = tmp_path / "o"
    r = subprocess.run(
        [sys.executable, "-m", "fxspace.cli", "sweep",
         str(ROOT / "configs" / "search_example.toml"), "--workers", "2", "--out", str(out)],
        env={**os.environ, "PYTHONPATH": str(ROOT), "FXSPACE_QUIET": "0"}, capture_output=True,
        text=True, timeout=900,
    )  # fmt: skip
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-3000:]
    assert "OperationalError" not in log and "Traceback" not in log and "IntegrityError" not in log
    assert "6 complete, 0 failed" in r.stdout
    study = optuna.load_study(study_name="search_example", storage=f"sqlite:///{out / 'search.db'}")
    done = [t for t in study.trials if t.state.name == "COMPLETE"]
    assert len({tuple(sorted(t.params.items())) for t in done}) == len(done) == 6
    trial_lines = [ln for ln in log.splitlines() if ln.startswith("[search] trial")]
    assert len(trial_lines) == 6 and all(re.match(r"\[search\] trial_\d{4} \(worker \d\)", ln)
                                         for ln in trial_lines)  # fmt: skip
    stages = [ln for ln in log.splitlines() if "loading frames" in ln]
    assert len(stages) == 6 and all(re.match(r"\[trial_\d{4}\] \[fxspace\]", ln) for ln in stages)
    assert "it/s" not in log  # no interleaved progress bars
