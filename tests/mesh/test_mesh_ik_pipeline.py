"""The mesh-IK experiment end to end on a reduced config (one small mesh, a few frames)."""

import json

import pytest

from fxspace.pipelines import run_dict


@pytest.mark.slow
def test_mesh_ik_pipeline_quick(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FXSPACE_DATA", str(data_dir))
    monkeypatch.delenv("FXSPACE_QUIET", raising=False)
    raw = {
        "experiment": "mesh_ik",
        "seed": 0,
        "meshes": ["RiggedSimple:"],
        "marker_counts": [1, 5, 10000],
        "num_frames": 4,
        "gradient_repeats": 1,
        "reg_mesh": "RiggedSimple:",
        "reg_marker_counts": [1],
    }
    (run,) = run_dict(raw, tmp_path / "out")
    err = capsys.readouterr().err  # a line per mesh and per marker count
    assert "[fxspace] mesh 1/1 loading RiggedSimple:" in err
    assert "mesh 1/1 RiggedSimple: 5 markers (2/2 marker counts)" in err
    m = json.loads((run / "metrics.json").read_text())
    r = m["meshes"]["RiggedSimple"]
    assert set(r["per_markers"]) == {"1", "5"} and r["skipped_marker_counts"] == [10000]
    row = r["per_markers"]["5"]
    for key in (
        "lm_cold_ms_mean",
        "bfgs_factored_warm_vertex_error",
        "ratio_naive_factored_cold",
        "ratio_naive_factored_gradient_loop",
        "gradient_loop_us_factored",
    ):
        assert row[key] > 0
    table = (run / "table.md").read_text()
    assert "| RiggedSimple | 5 | cold |" in table and "| RiggedSimple | 5 | warm |" in table
    # more markers pin the mesh better (RiggedSimple: 5 markers nearly exact)
    assert row["lm_warm_vertex_error"] < r["per_markers"]["1"]["lm_warm_vertex_error"]
    assert set(m["regularizers"]["vertex_error"]) == {
        "none",
        "joint prior",
        "joint limits",
        "normals",
        "all",
    }
    for name in ("poses", "time_per_frame", "time_vs_markers", "error_vs_markers"):
        assert (run / f"RiggedSimple_{name}.png").stat().st_size > 1000
    assert (run / "regularizers.png").is_file()
    table = (run / "table.md").read_text()
    assert "| RiggedSimple | 5 |" in table


def test_mesh_ik_config_is_validated():
    from fxspace.config import ConfigError, config_from_dict
    from fxspace.pipelines.mesh_ik import Config

    with pytest.raises(ConfigError):
        config_from_dict(Config, {"starts": ["lukewarm"]})
    with pytest.raises(ConfigError):
        config_from_dict(Config, {"view_dir": [0.0, 0.0]})
