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


def test_mesh_ik_declares_its_stages_and_parses_the_five_models():
    from fxspace.config import ConfigError
    from fxspace.pipelines import mesh_ik

    assert mesh_ik.STAGES == ("per_mesh", "regularizers")
    assert len(mesh_ik.Config().meshes) == 5
    mesh_ik.Config().validate()
    assert mesh_ik._parse_spec("CesiumMan+13800:Anim_0") == ("CesiumMan", 13800, "Anim_0")
    assert mesh_ik._parse_spec("chain48:wave") == ("chain", 48, "wave")
    with pytest.raises(ConfigError, match="meshes"):
        mesh_ik.Config(meshes=("chain1:wave",)).validate()
    with pytest.raises(ConfigError, match="meshes"):
        mesh_ik.Config(meshes=("Fox+many:Walk",)).validate()


@pytest.mark.slow
def test_mesh_ik_resumes_after_the_first_stage(data_dir, tmp_path, monkeypatch):
    """Interrupt after the per-mesh stage, rerun: the per-mesh results come from the cache
    (not recomputed) and the metrics hold them unchanged; a subdivided mesh and a chain
    run through the same stage, and the models figure and table are written."""
    import fxspace.runs
    from fxspace.pipelines import mesh_ik

    monkeypatch.setenv("FXSPACE_DATA", str(data_dir))
    # the run key holds a digest of the source: pin it, so an edit elsewhere in the tree
    # between the two runs cannot invalidate the cache this test checks
    monkeypatch.setattr(fxspace.runs, "code_digest", lambda: "fixed-code")
    raw = {
        "experiment": "mesh_ik",
        "seed": 0,
        "meshes": ["RiggedSimple:", "RiggedSimple+1500:", "chain6:wave"],
        "marker_counts": [3],
        "num_frames": 3,
        "naive_frames": 2,
        "starts": ["warm"],
        "gradient_repeats": 1,
        "reg_mesh": "RiggedSimple:",
        "reg_marker_counts": [2],
    }
    real_reg, real_mesh = mesh_ik._run_regularizers, mesh_ik._run_mesh
    calls = []

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(mesh_ik, "_run_regularizers", interrupt)
    monkeypatch.setattr(mesh_ik, "_run_mesh", lambda *a, **k: calls.append(1) or real_mesh(*a))
    with pytest.raises(KeyboardInterrupt):
        run_dict(raw, tmp_path / "a")
    assert len(calls) == 3
    cache = sorted(p.name for p in (tmp_path / "a").rglob("cache/per_mesh_*.json"))
    assert len(cache) == 3, cache
    monkeypatch.setattr(mesh_ik, "_run_regularizers", real_reg)
    (run,) = run_dict(raw, tmp_path / "a")
    assert len(calls) == 3  # every mesh came from the cache
    m = json.loads((run / "metrics.json").read_text())
    assert set(m["meshes"]) == {"RiggedSimple", "RiggedSimple+1500", "chain6"}
    assert m["meshes"]["chain6"]["depth"] == 6
    assert m["meshes"]["RiggedSimple+1500"]["vertices"] == 1500
    assert len(m["models"]["per evaluation"]) == 3
    assert (run / "models_speedup.png").stat().st_size > 1000
    assert "| chain6 |" in (run / "table.md").read_text()
