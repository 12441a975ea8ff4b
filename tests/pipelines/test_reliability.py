"""Issue 10, cases 3, 4 and 6: caches keyed by content, settings honoured or rejected,
clean failures at the edges (CLI, config paths, permissions)."""

import json
import os
import stat

import numpy as np
import pytest

import fxspace as fx
from fxspace.cli import main
from fxspace.config import ConfigError
from fxspace.pipelines import run_config, run_dict
from fxspace.runs import read_status, run_key

SMALL = {
    "experiment": "threshold_sweep",
    "seed": 3,
    "data": {"source": "synthetic", "synthetic_frames": 100, "synthetic_markers": 12},
    "graph": {"num_thresholds": 3, "batch_size": 3},
}


def _with(**patch):
    raw = json.loads(json.dumps(SMALL))
    for k, v in patch.items():
        head, _, key = k.partition("__")
        if key:
            raw.setdefault(head, {})[key] = v
        else:
            raw[head] = v
    return raw


def _metrics(d):
    return json.loads((d / "metrics.json").read_text())


def test_changed_config_never_reuses_or_overwrites(tmp_path, capsys):
    (d,) = run_dict(SMALL, tmp_path / "a")
    first = _metrics(d)
    assert read_status(d)["status"] == "complete"
    changed = _with(data__synthetic_noise_mm=5.0)
    # a finished run of another config is not overwritten without --force
    with pytest.raises(ConfigError, match=r"different config.*synthetic_noise_mm.*--force"):
        run_dict(changed, tmp_path / "a")
    assert _metrics(d) == first
    # --force recomputes: no chunk of the old cache is served
    (d2,) = run_dict(changed, tmp_path / "a", force=True)
    again = _metrics(d2)
    (fresh,) = run_dict(changed, tmp_path / "fresh")
    assert again["sweep"] == _metrics(fresh)["sweep"]
    assert again["sweep"] != first["sweep"]


def test_interrupted_run_with_changed_config_does_not_reuse_cache(tmp_path):
    (d,) = run_dict(SMALL, tmp_path / "a")
    (d / "metrics.json").unlink()  # an interrupted run: cache present, no metrics
    changed = _with(data__synthetic_noise_mm=5.0)
    (d2,) = run_dict(changed, tmp_path / "a")
    (fresh,) = run_dict(changed, tmp_path / "fresh")
    assert _metrics(d2)["sweep"] == _metrics(fresh)["sweep"]


def test_force_clears_the_cache(tmp_path):
    (d,) = run_dict(SMALL, tmp_path / "a")
    entries = sorted(p for p in (d / "cache").iterdir() if p.name != "KEY")
    assert entries
    entries[0].write_bytes(b"poisoned")  # a stage that --force must not serve again
    run_dict(SMALL, tmp_path / "a", force=True)
    assert entries[0].read_bytes() != b"poisoned"


def test_run_key_covers_config_data_and_code(tmp_path):
    f = tmp_path / "x.trc"
    f.write_text("a")
    k = run_key("cfg", [f], code="c1")
    assert run_key("cfg2", [f], code="c1") != k
    assert run_key("cfg", [f], code="c2") != k
    f.write_text("b")
    assert run_key("cfg", [f], code="c1") != k


def test_failed_run_leaves_a_marker(tmp_path, monkeypatch):
    import fxspace.pipelines.threshold_sweep as ts

    def boom(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(ts, "_run", boom)
    with pytest.raises(RuntimeError):
        run_dict(SMALL, tmp_path / "f")
    st = read_status(tmp_path / "f")
    assert st["status"] == "failed" and "disk on fire" in st["error"]
    assert not (tmp_path / "f" / "metrics.json").exists()

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(ts, "_run", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_dict(SMALL, tmp_path / "i")
    assert read_status(tmp_path / "i")["status"] == "interrupted"


def test_sweep_honours_dim_and_dtype(tmp_path):
    (d,) = run_dict(_with(dim=3, graph__dtype="float64"), tmp_path / "x")
    m = _metrics(d)
    assert m["dtype"] == "float64" and m["dim"] == 3 and len(m["eigenvalues"]) == 3
    emb = np.load(d / "expression_space.npz")["embedding"]
    assert emb.shape == (100, 3)
    (d32,) = run_dict(_with(graph__dtype="float32"), tmp_path / "y")
    assert _metrics(d32)["dtype"] == "float32"


@pytest.mark.parametrize(
    "patch, match",
    [
        ({"select__max_mean_degree": -10}, "max_mean_degree"),
        ({"select__max_mean_degree": float("nan")}, "max_mean_degree"),
        ({"graph__upper_quantile": 2.0}, "upper_quantile"),
        ({"seed": -1}, "seed"),
        ({"data__max_gap": -1}, "max_gap"),
        ({"data__missing": "zero"}, "missing"),
        ({"graph__thresholds": [1.0, float("inf")]}, "finite"),
        ({"graph__unknown": 1}, "unknown config key"),
    ],
)
def test_bad_values_rejected(tmp_path, patch, match):
    with pytest.raises(ConfigError, match=match):
        run_dict(_with(**patch), tmp_path / "r")
    assert not (tmp_path / "r").exists()


def test_sweep_validated_before_the_first_run(tmp_path):
    raw = dict(SMALL, sweep={"select.max_mean_degree": [50.0, -10.0]})
    with pytest.raises(ConfigError, match="max_mean_degree.*sweep run"):
        run_dict(raw, tmp_path)
    assert not any(tmp_path.iterdir())  # nothing ran


def test_missing_data_counts_in_metrics(tmp_path):
    syn = fx.synthetic.synthetic_face(n_frames=150, n_markers=12, seed=0).sequence
    pos = np.asarray(syn.positions).copy()
    pos[40:44, 2] = np.nan  # filled (4 ≤ max_gap)
    pos[90:120, 5] = np.nan  # 30 frames: dropped
    f = tmp_path / "take.trc"
    fx.io.write_trc(f, fx.io.MarkerSequence(pos, syn.names, syn.rate, syn.units))
    raw = {
        "experiment": "threshold_sweep",
        "data": {"source": "files", "paths": ["take.trc"], "missing": "fill", "max_gap": 5},
        "graph": {"num_thresholds": 3, "batch_size": 3},
    }
    cfg = tmp_path / "cfg" / "c.toml"
    cfg.parent.mkdir()
    from fxspace.config import dumps_toml

    # relative paths resolve against the config file's folder (not the working directory)
    (cfg.parent / "take.trc").write_bytes(f.read_bytes())
    cfg.write_text(dumps_toml(raw))
    (d,) = run_config(cfg, tmp_path / "out")
    m = _metrics(d)["missing"]
    assert m["policy"] == "fill" and m["filled_frames"] == 4 and m["dropped_frames"] == 30
    frames = np.load(d / "expression_space.npz")["frame"]
    assert len(frames) == 120 and not np.isin(np.arange(90, 120), frames).any()
    assert "/cfg/take.trc" in (d / "config.toml").read_text()  # resolved, absolute
    raw["data"]["paths"] = [str(f)]  # absolute paths are kept
    (d2,) = run_dict(raw, tmp_path / "abs")
    assert str(f) in (d2 / "config.toml").read_text()
    raw["data"]["paths"] = ["nope.trc"]
    cfg.write_text(dumps_toml(raw))
    with pytest.raises(ConfigError, match=r"nope.trc does not exist.*config file"):
        run_config(cfg, tmp_path / "o2")
    raw["data"]["missing"] = "raise"
    raw["data"]["paths"] = ["take.trc"]
    cfg.write_text(dumps_toml(raw))
    with pytest.raises(fx.FxspaceError, match=r"frames 40–43"):
        run_config(cfg, tmp_path / "o3")


def test_outputs_are_group_readable(tmp_path):
    old = os.umask(0o022)
    try:
        (d,) = run_dict(SMALL, tmp_path / "p")
    finally:
        os.umask(old)
    for f in ("metrics.json", "config.toml", "r_vs_threshold.png", "expression_space.npz"):
        mode = stat.S_IMODE((d / f).stat().st_mode)
        assert mode & stat.S_IRGRP and mode & stat.S_IROTH, (f, oct(mode))


# --- CLI edges -------------------------------------------------------------------------


def test_cli_error_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('experiment = "threshold_sweep"\nseed = -1\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fxspace: error:") and "seed" in err and "\n" not in err


def test_cli_unwritable_out_names_path(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    from fxspace.config import dumps_toml

    cfg.write_text(dumps_toml(SMALL))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["run", str(cfg), "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert str(blocker) in err and "Traceback" not in err


def test_cli_ctrl_c(tmp_path, capsys, monkeypatch):
    import fxspace.pipelines as pl

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(pl, "run_config", interrupted)
    assert main(["run", str(tmp_path / "c.toml")]) == 130
    assert "interrupted; rerun to resume" in capsys.readouterr().err


def test_cli_version_and_bench_list(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and fx.__version__ in capsys.readouterr().out
    assert main(["bench"]) == 0
    out = capsys.readouterr().out
    assert "geodesic" in out and "distances" in out


def test_python_m_fxspace_is_the_command():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "fxspace", "--version"], capture_output=True,
                       text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0 and fx.__version__ in r.stdout, r.stderr[-2000:]


def test_cli_demo_real_has_its_own_folder(monkeypatch):
    import fxspace.pipelines as pl

    seen = []
    monkeypatch.setattr(pl, "run_dict", lambda raw, out, force: seen.append(str(out)) or [])
    main(["demo", "--real"])
    main(["demo"])
    assert seen == ["runs/demo_real", "runs/demo"]


# --- a user's folders are theirs (issue 19): fxspace deletes only what it wrote ---------


def test_user_file_in_cache_survives_a_rerun_of_another_config(tmp_path):
    from fxspace.runs import MANIFEST, manifest_files

    out = tmp_path / "r"
    (out / "cache").mkdir(parents=True)
    mine = out / "cache" / "my_notes.txt"
    mine.write_text("keep me")
    (out / "keep.csv").write_text("1,2")
    (d,) = run_dict(SMALL, out)
    listed = manifest_files(d)
    assert (d / MANIFEST).is_file() and "metrics.json" in listed and "cache/KEY" in listed
    assert any(r.startswith("cache/") and r != "cache/KEY" for r in listed)
    assert "cache/my_notes.txt" not in listed and "keep.csv" not in listed
    # a changed config with --force clears the cache: only fxspace's files go
    run_dict(_with(data__synthetic_noise_mm=5.0), out, force=True)
    assert mine.read_text() == "keep me" and (out / "keep.csv").read_text() == "1,2"
    # the CLI path as the issue tried it
    cfg = tmp_path / "c.toml"
    from fxspace.config import dumps_toml

    cfg.write_text(dumps_toml(_with(data__synthetic_noise_mm=2.0)))
    assert main(["run", str(cfg), "--out", str(out), "--force"]) == 0
    assert mine.read_text() == "keep me"


def test_reset_cache_deletes_only_listed_files(tmp_path):
    from fxspace.runs import cached, cached_arrays, reset_cache

    reset_cache(tmp_path, "k1")
    cached(tmp_path, "a", lambda: {"v": 1})
    cached_arrays(tmp_path, "stage", lambda: {"x": np.arange(3)})
    (tmp_path / "cache" / "user.bin").write_bytes(b"\x00")
    (tmp_path / "cache" / "sub").mkdir()
    (tmp_path / "cache" / "sub" / "deep.txt").write_text("x")
    assert reset_cache(tmp_path, "k2")
    left = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert "cache/user.bin" in left and "cache/sub/deep.txt" in left
    assert "cache/a.json" not in left and "cache/stage.npz" not in left
    assert (tmp_path / "cache" / "KEY").read_text().strip() == "k2"


def test_force_into_another_experiment_removes_its_outputs(tmp_path):
    from fxspace.runs import manifest_files

    out = tmp_path / "r"
    (d,) = run_dict(SMALL, out)
    old_fig = d / "r_vs_threshold.png"
    assert old_fig.is_file()
    stale = d / "old_only.png"  # a figure only the old experiment wrote (via fxspace)
    from fxspace.runs import record, write_bytes_atomic

    write_bytes_atomic(stale, b"png")
    record(d, stale)
    (d / "user_plot.png").write_bytes(b"theirs")
    run_dict(_with(dim=3), out, force=True)
    assert not stale.exists()  # the old experiment's output is gone ...
    assert (d / "user_plot.png").read_bytes() == b"theirs"  # ... the user's file stays
    assert "old_only.png" not in manifest_files(d)
    assert _metrics(d)["dim"] == 3


@pytest.mark.slow  # three sweep runs
def test_force_single_run_over_an_old_sweep(tmp_path):
    out = tmp_path / "s"
    raw = dict(SMALL, sweep={"graph.num_thresholds": [2, 3]})
    dirs = run_dict(raw, out)
    assert len(dirs) == 2 and all((x / "metrics.json").is_file() for x in dirs)
    (dirs[0] / "notes.md").write_text("mine")
    with pytest.raises(ConfigError, match="--force"):
        run_dict(dict(SMALL), dirs[0])  # a finished sweep run of another config
    run_dict(dict(SMALL), out, force=True)
    # issue 33: --force on a parent folder leaves every nested run intact (it used to
    # empty them); the single run is written beside them
    assert (dirs[1] / "metrics.json").is_file() and (dirs[0] / "metrics.json").is_file()
    assert (dirs[0] / "notes.md").read_text() == "mine"
    assert (out / "metrics.json").is_file()


def test_user_files_named_like_run_files_are_not_overwritten(tmp_path):
    out = tmp_path / "u"
    out.mkdir()
    (out / "config.toml").write_text("# my own config\n")
    with pytest.raises(ConfigError, match="did not write"):
        run_dict(SMALL, out)
    assert (out / "config.toml").read_text() == "# my own config\n"


def test_demo_refuses_to_overwrite_another_finished_run(tmp_path, capsys):
    out = str(tmp_path / "demo")
    (d,) = run_dict(SMALL, out)
    first = _metrics(d)
    assert main(["demo", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "different config" in err and "--force" in err
    assert _metrics(d) == first


def test_demo_force_and_resume(tmp_path, monkeypatch):
    import fxspace.cli as cli
    import fxspace.runs as runs

    monkeypatch.setattr(cli, "_DEMO", dict(SMALL))
    monkeypatch.setattr(runs, "code_digest", lambda: "fixed")  # others may edit the tree
    out = str(tmp_path / "demo")
    assert main(["demo", "--out", out]) == 0
    t = (tmp_path / "demo" / "metrics.json").stat().st_mtime_ns
    assert main(["demo", "--out", out]) == 0  # same config: reused, not recomputed
    assert (tmp_path / "demo" / "metrics.json").stat().st_mtime_ns == t
    assert main(["demo", "--out", out, "--seed", "4"]) == 2  # another finished run
    assert main(["demo", "--out", out, "--seed", "4", "--force"]) == 0
    assert "seed = 4" in (tmp_path / "demo" / "config.toml").read_text()


# --- the Pipeline protocol (issue 18, item 5) --------------------------------------------


@pytest.mark.parametrize("name", __import__("fxspace.pipelines").pipelines.available())
def test_every_pipeline_satisfies_the_protocol(name):
    from fxspace.pipelines import check_pipeline, load_pipeline

    mod = load_pipeline(name)
    assert check_pipeline(mod) is mod
    assert isinstance(mod.STAGES, tuple) and all(isinstance(s, str) for s in mod.STAGES)
    cfg = mod.Config()
    cfg.validate()  # the default config is valid


def test_malformed_pipeline_is_refused():
    import dataclasses
    import types

    from fxspace.pipelines import PipelineError, check_pipeline, register

    bad = types.ModuleType("fxspace_bad_pipeline")
    with pytest.raises(PipelineError, match=r"Config.*STAGES.*run\(cfg, run_dir, seed\)"):
        check_pipeline(bad)

    @dataclasses.dataclass
    class Config:  # not frozen, no validate
        a: int = 1

    bad.Config = Config
    bad.STAGES = ["x"]
    bad.run = lambda cfg, run_dir: {}
    with pytest.raises(PipelineError) as e:
        register(bad, "bad_one")
    msg = str(e.value)
    assert "frozen" in msg and "validate" in msg and "STAGES" in msg and "run(" in msg
    assert "bad_one" not in __import__("fxspace.pipelines").pipelines.available()


def test_registered_pipeline_runs_and_validate_is_called(tmp_path):
    import dataclasses
    import types

    from fxspace.pipelines import _REGISTERED, available, register

    calls = []

    @dataclasses.dataclass(frozen=True)
    class Config:
        n: int = 2

        def validate(self):
            calls.append(self.n)
            if self.n < 1:
                raise ConfigError("n must be >= 1")

    mod = types.ModuleType("toy")
    mod.Config, mod.STAGES = Config, ("square",)
    mod.run = lambda cfg, run_dir, seed: {"sq": cfg.n**2}
    try:
        assert register(mod) == "toy" and "toy" in available()
        (d,) = run_dict({"experiment": "toy", "n": 3}, tmp_path / "t")
        assert _metrics(d)["sq"] == 9 and 3 in calls
        with pytest.raises(ConfigError, match="n must be >= 1"):
            run_dict({"experiment": "toy", "n": 0}, tmp_path / "t0")
    finally:
        _REGISTERED.pop("toy", None)


def test_legacy_cache_without_manifest_is_set_aside_not_deleted(tmp_path):
    from fxspace.runs import cached, reset_cache

    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "KEY").write_text("old\n")
    (tmp_path / "cache" / "stage.json").write_text('{"v": 1}')  # no manifest: unknown origin
    assert reset_cache(tmp_path, "new")
    aside = [p for p in tmp_path.iterdir() if p.name.startswith("cache.stale-")]
    assert len(aside) == 1 and (aside[0] / "stage.json").read_text() == '{"v": 1}'
    assert cached(tmp_path, "stage", lambda: {"v": 2}) == {"v": 2}  # never the stale entry
