"""The navigation pipeline: its own threshold sweep (the paper's rule, on the navigated
frames), cached stages and resume (Pipeline protocol)."""

import json

import numpy as np
import pytest

import fxspace.pipelines.navigation as nav
import fxspace.pipelines.threshold_sweep as ts
from fxspace.pipelines import run_dict

SMALL = {
    "experiment": "navigation",
    "seed": 0,
    "data": {"source": "synthetic", "synthetic_frames": 80, "synthetic_markers": 20},
    "graph": {"threshold": "max_r", "num_thresholds": 4},
    "hierarchy": {"c0": 8, "restarts": 0, "compare_cold": False},
    "navigation": {"animation": "none", "level_figures": False},
}


@pytest.fixture(autouse=True)
def _fixed_code_digest(monkeypatch):
    import fxspace.runs

    monkeypatch.setattr(fxspace.runs, "code_digest", lambda: "test-code")


def _metrics(d):
    m = json.loads((d / "metrics.json").read_text())
    m.pop("timings"), m.pop("wall_time_s", None)
    assert all("fcm_time_s" not in lv for lv in m["levels"])  # timings live in "timings"
    return m


def test_threshold_from_its_own_sweep_by_the_papers_rule(tmp_path):
    (d,) = run_dict(SMALL, tmp_path / "run")
    m = _metrics(d)
    assert m["criterion"] == "max_r" and "criterion max_r" in m["threshold_source"]
    assert len(m["sweep"]) == 4
    rs = [s["r"] for s in m["sweep"] if s["r"] is not None]
    best = max(m["sweep"], key=lambda s: -np.inf if s["r"] is None else s["r"])
    assert m["threshold"] == pytest.approx(best["threshold"]) and max(rs) == best["r"]
    assert (
        m["sweep"][-1]["threshold"]
        > m["sweep"][0]["threshold"]
        == pytest.approx(m["connecting_threshold"], rel=1e-6)
    )
    for name in nav.STAGES:  # cold_levels is compare_cold's stage, off here
        cached = (d / "cache" / f"{name}.npz").is_file()
        assert cached == (name != "cold_levels"), name
    assert m["path_is_graph_walk"] is True
    # the paper's rule alone by default: no bridges; the pieces each level is left in
    assert m["links_bridged"] == 0 == sum(lv["bridges"] or 0 for lv in m["levels"])
    assert all(lv["link_pieces"] >= 1 for lv in m["levels"] if lv["links"] is not None)
    assert m["link_pieces_finest"] == m["levels"][-1]["link_pieces"]
    # ρ by the paper's experiment: the table of links and coverage against ρ, the
    # scale chosen (the largest joining every swept level) and its figure
    rx = m["rho_experiment"]
    cov = np.asarray([lv["coverage"] for lv in rx["levels"]])
    joined = np.flatnonzero(cov.min(axis=0) >= 1.0)
    if len(joined):
        assert rx["chosen_scale"] == rx["scales"][joined[-1]]
        swept = {lv["centres"] for lv in rx["levels"]}
        assert all(lv["bridges"] == 0 for lv in m["levels"] if lv["centres"] in swept)
    assert (d / "link_radius.png").is_file()


def test_bridges_option_counted(tmp_path):
    """``hierarchy.bridges = true`` with wide circles (ρ = 3 spacings, levels in pieces):
    every level joined, the links outside the rule counted as links_bridged."""
    raw = {**SMALL, "hierarchy": {**SMALL["hierarchy"], "rho_scale": 3.0, "bridges": True}}
    (d,) = run_dict(raw, tmp_path / "run")
    m = _metrics(d)
    assert m["links_bridged"] == sum(lv["bridges"] for lv in m["levels"]) > 0
    assert all(lv["link_graph_connected"] and lv["link_pieces"] == 1 for lv in m["levels"])
    assert m["path_is_graph_walk"] is True


def test_interrupted_after_the_sweep_resumes(tmp_path, monkeypatch):
    """Interrupt after the first costly stage (sweep), rerun: identical metrics, the sweep
    not recomputed; the hierarchy stage round-trips exactly."""
    assert nav.STAGES == ("sweep", "space", "hierarchy", "cold_levels")
    (ref,) = run_dict(SMALL, tmp_path / "ref")
    calls = []
    real_sweep, real_space = ts.threshold_sweep, nav._space
    monkeypatch.setattr(
        ts, "threshold_sweep", lambda *a, **k: calls.append(1) or real_sweep(*a, **k)
    )

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(nav, "_space", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_dict(SMALL, tmp_path / "a")
    assert (tmp_path / "a" / "cache" / "sweep.npz").is_file() and len(calls) == 4
    monkeypatch.setattr(nav, "_space", real_space)
    (d,) = run_dict(SMALL, tmp_path / "a")
    assert len(calls) == 4  # the sweep came from the cache
    assert _metrics(d) == _metrics(ref)


def test_config_validate_names_the_key():
    from fxspace.config import ConfigError

    for bad, key in [
        (nav.GraphConfig(threshold="best"), "graph.threshold"),
        (nav.GraphConfig(threshold=-1.0), "graph.threshold"),
        (nav.GraphConfig(num_thresholds=1), "num_thresholds"),
        (nav.NavConfig(fps=0.0), "fps"),
        (nav.NavConfig(duration=-1.0), "duration"),
        (nav.HierarchyConfig(rho_scale=0.0), "rho_scale"),
    ]:
        with pytest.raises(ConfigError, match=key):
            bad.validate()
