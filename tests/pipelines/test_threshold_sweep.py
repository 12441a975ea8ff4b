import json
import subprocess
import sys

import numpy as np
import pytest

from fxspace.cli import main
from fxspace.config import ConfigError
from fxspace.pipelines import run_dict


@pytest.fixture(autouse=True)
def _fixed_code_digest(monkeypatch):
    """Other work in the tree changes the code digest mid-test; the reuse logic is what
    these tests check, so the digest is held fixed."""
    import fxspace.runs

    monkeypatch.setattr(fxspace.runs, "code_digest", lambda: "test-code")


SMALL = {
    "experiment": "threshold_sweep",
    "seed": 3,
    "data": {"source": "synthetic", "synthetic_frames": 240, "synthetic_markers": 30},
    "graph": {"num_thresholds": 6, "batch_size": 3},
}


def test_synthetic_run_folder(tmp_path):
    (d,) = run_dict(SMALL, tmp_path / "run")
    for f in (
        "config.toml",
        "meta.json",
        "metrics.json",
        "r_vs_threshold.png",
        "expression_space.png",
        "expression_space.npz",
    ):
        assert (d / f).is_file() and (d / f).stat().st_size > 0, f
    m = json.loads((d / "metrics.json").read_text())
    meta = json.loads((d / "meta.json").read_text())
    assert meta["seed"] == 3 and "jax" in meta["versions"]
    assert len(m["sweep"]) == 6 and m["frames"] == 240
    assert 0.9 < m["r_at_best"] <= 1.0
    assert m["best_threshold"] >= m["connecting_threshold"]
    assert set(m["choices"]) == {"max_r", "bounded_degree", "elbow"}
    # the paper's criterion by default, over the whole range up to the largest distance
    assert m["criterion"] == "max_r" and m["best_threshold"] == m["choices"]["max_r"]["threshold"]
    assert m["thresholds_reach_largest_distance"]
    assert m["sweep"][-1]["threshold"] == pytest.approx(m["largest_distance"], rel=1e-6)
    assert m["sweep"][0]["threshold"] == pytest.approx(m["connecting_threshold"], rel=1e-6)
    rs = [e["r"] for e in m["sweep"] if e["r"] is not None]
    assert m["choices"]["max_r"]["score"] == pytest.approx(max(rs))
    emb = np.load(d / "expression_space.npz")["embedding"]
    assert emb.shape == (240, 2) and np.isfinite(emb).all()


def test_interrupted_after_the_sweep_resumes_without_resweeping(tmp_path, monkeypatch):
    """Pipeline protocol: interrupt after the first costly stage (sweep), rerun: identical
    metrics, the sweep not recomputed."""
    import fxspace.pipelines.threshold_sweep as ts

    assert ts.STAGES == ("sweep", "space")
    (ref,) = run_dict(SMALL, tmp_path / "ref")
    calls = []
    real_sweep, real_space = ts.threshold_sweep, ts._space_arrays
    monkeypatch.setattr(
        ts, "threshold_sweep", lambda *a, **k: calls.append(1) or real_sweep(*a, **k)
    )

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(ts, "_space_arrays", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_dict(SMALL, tmp_path / "a")
    assert (tmp_path / "a" / "cache" / "sweep.npz").is_file() and len(calls) == 2  # 6 / 3
    monkeypatch.setattr(ts, "_space_arrays", real_space)
    (d,) = run_dict(SMALL, tmp_path / "a")
    assert len(calls) == 2  # the sweep came from the cache
    a, b = (json.loads((x / "metrics.json").read_text()) for x in (ref, d))
    for m in (a, b):
        m.pop("timings"), m.pop("wall_time_s", None)
    assert a == b


def test_rerun_is_reproducible_and_resumes(tmp_path, capsys):
    (d,) = run_dict(SMALL, tmp_path / "a")
    first = json.loads((d / "metrics.json").read_text())
    run_dict(SMALL, tmp_path / "a")  # complete: skipped
    assert "already complete" in capsys.readouterr().out
    # an interrupted run: metrics gone, cache kept -> same numbers
    (d / "metrics.json").unlink()
    run_dict(SMALL, tmp_path / "a")
    again = json.loads((d / "metrics.json").read_text())
    assert again["sweep"] == first["sweep"]
    (d2,) = run_dict(SMALL, tmp_path / "b")
    fresh = json.loads((d2 / "metrics.json").read_text())
    assert fresh["sweep"] == first["sweep"] and fresh["r_at_best"] == first["r_at_best"]


def test_sweep_table_expands(tmp_path):
    raw = dict(SMALL, sweep={"graph.num_thresholds": [4, 5]})
    dirs = run_dict(raw, tmp_path)
    assert sorted(d.name for d in dirs) == ["num_thresholds=4", "num_thresholds=5"]


@pytest.mark.parametrize(
    "patch, match",
    [
        ({"experiment": "nope"}, "not known"),
        ({"graph": {"num_thresholds": 1}}, "num_thresholds"),
        ({"data": {"source": "files"}}, "paths"),
        ({"seed": "x"}, "seed"),
        ({"select": {"criterion": "best"}}, "criterion"),
    ],
)
def test_bad_configs(tmp_path, patch, match):
    with pytest.raises(ConfigError, match=match):
        run_dict({**SMALL, **patch}, tmp_path)
    assert not (tmp_path / "metrics.json").exists()


def test_cli_help_and_errors(tmp_path, capsys):
    r = subprocess.run(
        [sys.executable, "-m", "fxspace.cli", "--help"], capture_output=True, text=True, check=False
    )
    assert r.returncode == 0 and "demo" in r.stdout and "run" in r.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text('experiment = "threshold_sweep"\n[graph]\nnum_thresholds = 0\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "num_thresholds" in capsys.readouterr().err


@pytest.mark.data
def test_real_animface_subsample(tmp_path, data_dir):
    raw = {
        "experiment": "threshold_sweep",
        "seed": 0,
        "data": {"source": "animface", "max_frames": 300},
        "graph": {"num_thresholds": 5, "batch_size": 5},
    }
    (d,) = run_dict(raw, tmp_path)
    m = json.loads((d / "metrics.json").read_text())
    assert m["markers"] == 41 and m["frames"] == 300
    assert m["takes"] == ["animface_cheeks.c3d", "animface_jaw.c3d", "animface_eyebrows.trc.gz"]
    rs = [s["r"] for s in m["sweep"] if s["connected"]]
    assert rs and all(0.5 < r <= 1.0 for r in rs)
    assert m["sweep"][0]["connected"]  # the grid starts at the connecting threshold
    assert m["thresholds_reach_largest_distance"] and m["criterion"] == "max_r"


def test_sweep_stage_threads_keep_float64_and_order(tmp_path):
    """The stage runs two ε at a time in worker threads: in float64 when the run is (a
    thread does not inherit jax.enable_x64), in the grid's order, each chunk cached."""
    import jax

    from fxspace.expression import threshold_grid, threshold_sweep
    from fxspace.pipelines.threshold_sweep import state_distances, sweep_stage

    X = np.random.default_rng(3).normal(size=(40, 6, 3)).cumsum(axis=0)
    with jax.enable_x64(True):
        P = state_distances(X, "float64")
        th = np.asarray(threshold_grid(P, 5), np.float64)
        sw = sweep_stage(tmp_path, P, th)
        ref = threshold_sweep(P, th)
    np.testing.assert_array_equal(np.asarray(sw.thresholds), th)
    np.testing.assert_allclose(np.asarray(sw.scores), np.asarray(ref.scores), rtol=1e-12)
    assert len(list((tmp_path / "cache").glob("sweep_0*.npz"))) == 5


def test_sweep_interrupted_mid_way_keeps_what_finished(tmp_path, monkeypatch):
    """Ctrl-C (a real SIGINT) in the middle of the threaded sweep: it stops, the ε not
    started are dropped (not run), the finished ε stay cached and a rerun computes only
    the rest."""
    import os
    import signal
    import threading
    import time

    import fxspace.pipelines.threshold_sweep as ts
    from fxspace.expression import threshold_grid

    X = np.random.default_rng(4).normal(size=(30, 5, 3)).cumsum(axis=0)
    P = ts.state_distances(X)
    th = np.asarray(threshold_grid(P, 12), np.float64)
    real, calls, lock = ts.threshold_sweep, [], threading.Lock()

    def slow(*a, **k):  # each ε takes a while, as on real data
        with lock:
            calls.append(1)
            n = len(calls)
        if n == 3:
            os.kill(os.getpid(), signal.SIGINT)  # the user presses Ctrl-C
        # after the interrupt the workers take long enough for a loaded machine to wake
        # the main thread before either could start another ε
        time.sleep(0.2 if n < 3 else 2.0)
        return real(*a, **k)

    monkeypatch.setattr(ts, "threshold_sweep", slow)
    # Ctrl-C raises KeyboardInterrupt even where this process was started with SIGINT
    # ignored (a shell's background job)
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            ts.sweep_stage(tmp_path, P, th)
    finally:
        signal.signal(signal.SIGINT, old)
    for t in threading.enumerate():  # the signal may wake the main thread late
        if t.name.startswith("fxspace-sweep"):
            t.join(10)
    assert len(calls) <= 4  # the ε queued behind the interrupt never ran
    kept = len(list((tmp_path / "cache").glob("sweep_0*.npz")))
    assert kept == len(calls) and not (tmp_path / "cache" / "sweep.npz").exists()
    calls.clear()
    monkeypatch.setattr(ts, "threshold_sweep", lambda *a, **k: calls.append(1) or real(*a, **k))
    sw = ts.sweep_stage(tmp_path, P, th)
    assert len(calls) == len(th) - kept and len(np.asarray(sw.scores)) == len(th)
