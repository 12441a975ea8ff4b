"""`fx.pipelines.resolve_config`: the one room where a TOML becomes runs (CLI, pipelines
and apps read configs through it)."""

from pathlib import Path

import pytest

import fxspace as fx
from fxspace.config import ConfigError
from fxspace.pipelines import RunSpec, resolve_config

ROOT = Path(__file__).resolve().parents[2]


def test_a_sweep_resolves_to_its_runs_validated_in_order():
    specs = resolve_config(ROOT / "configs" / "sweep_example.toml", "/tmp/out")
    assert [s.label for s in specs] == [
        "dim=2_num_thresholds=3", "dim=2_num_thresholds=5",
        "dim=3_num_thresholds=3", "dim=3_num_thresholds=5",
    ]  # fmt: skip
    assert all(isinstance(s, RunSpec) and s.run_dir == Path("/tmp/out") / s.label for s in specs)
    assert [(s.config.dim, s.config.graph.num_thresholds) for s in specs] == [
        (2, 3), (2, 5), (3, 3), (3, 5)
    ]  # fmt: skip
    assert all(s.pipeline.__name__ == "fxspace.pipelines.threshold_sweep" for s in specs)
    assert 'experiment = "threshold_sweep"' in specs[0].text and "[sweep]" not in specs[0].text


def test_a_file_a_run_folder_and_a_dict(tmp_path):
    (spec,) = resolve_config(ROOT / "configs" / "navigation.toml")
    assert spec.run_dir == Path("runs") / "navigation" and spec.label == "" and spec.seed == 0
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.toml").write_text(spec.text)  # what a run folder keeps
    (again,) = resolve_config(run)
    assert again.run_dir == run and again.config == spec.config and again.text == spec.text
    (d,) = resolve_config({"experiment": "threshold_sweep", "seed": 3})
    assert d.seed == 3 and d.run_dir == Path("runs") / "config"


def test_relative_data_paths_resolve_against_the_config_folder(tmp_path):
    (tmp_path / "take.trc").write_text("x")
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        'experiment = "threshold_sweep"\n[data]\nsource = "files"\npaths = ["take.trc"]\n'
    )
    (spec,) = resolve_config(cfg)
    assert spec.config.data.paths == (str(tmp_path / "take.trc"),)


def test_refusals_name_the_file_and_the_fix(tmp_path):
    nav = ROOT / "configs" / "navigation.toml"
    msg = r"navigation.toml: experiment must be 'mesh_ik'.*'navigation'"
    with pytest.raises(ConfigError, match=msg):
        resolve_config(nav, experiment="mesh_ik")
    bad = tmp_path / "bad.toml"
    bad.write_text('experiment = "threshold_sweep"\n[graph]\nnum_thresholds = 0\n')
    with pytest.raises(ConfigError, match=r"bad.toml: .*num_thresholds"):
        resolve_config(bad)
    with pytest.raises(ConfigError, match="not a config file nor a run folder"):
        resolve_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="search"):
        resolve_config(ROOT / "configs" / "search_example.toml")
    with pytest.raises(ConfigError, match="config must be"):
        resolve_config(3)


def test_apps_read_configs_through_it(tmp_path):
    """The motion app's set-up loader refuses another experiment with the same words."""
    with pytest.raises(ConfigError, match="experiment must be 'parametric_synthesis'"):
        fx.pipelines.parametric_synthesis.load_setup(ROOT / "configs" / "navigation.toml")
