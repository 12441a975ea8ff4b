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
    from fxspace.runs import collect

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
    assert run_config(cfg, out) == []  # the study holds its trials: nothing more to run
    assert len(collect(out)) == 3
    raw["search"].update(metric="no_such_metric", trials=1)
    cfg.write_text(dumps_toml(raw))
    (bad,) = sweep_config(cfg, tmp_path / "bad", workers=1, engine="serial")
    assert bad["status"] == "failed" and "no_such_metric" in bad["error"]
    with pytest.raises(ConfigError, match=r"\[search\]"):
        run_dict(raw, tmp_path / "x")
