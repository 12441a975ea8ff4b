"""Issue 31.9: ``fxspace studio CONFIG`` builds only what the app shows
(`fxspace.pipelines.prepare_config` → the experiment's ``prepare_app``), in the run's own
folder and stages, so that ``fxspace run`` completes the run reusing them."""

from __future__ import annotations

import json

import numpy as np

from fxspace.config import dumps_toml
from fxspace.pipelines import prepare_config, run_config
from fxspace.runs import read_status

SMALL = {
    "experiment": "reconstruction",
    "seed": 0,
    "file": "synthetic",
    "start": 0,
    "n_frames": 80,
    "n_vertices": 300,
    "n_segments": 2,
    "clusters": [6, 8],
    "gammas": [0.5],
    "n_init": 2,
    "fit_steps": 5,
    "timing_repeats": 1,
    "character": "",
    "head": "",
    "gltf_mesh": "",
    "x64": False,
}


def test_editor_app_stages_then_the_run_completes_reusing_them(tmp_path):
    cfg = tmp_path / "rec.toml"
    cfg.write_text(dumps_toml(SMALL))
    out = tmp_path / "run"
    d = prepare_config(cfg, out)
    assert d == out and read_status(d)["status"] == "partial"
    assert not (d / "metrics.json").exists()
    z = np.load(d / "scene.npz")
    assert z["original"].shape == (40, z["original"].shape[1], 3) and "boundaries" in z
    assert json.loads((d / "edits.json").read_text())["keys"]  # the demonstration edit
    from fxspace.studio import load_editor_data

    data = load_editor_data(d)
    assert data.scene.segments[0].controls.shape[0] == 8  # the grid's middle: [6, 8][1]
    dense = d / "cache" / "dense.npz"
    before = dense.stat().st_mtime_ns
    assert prepare_config(cfg, out) == out and dense.stat().st_mtime_ns == before  # read
    (done,) = run_config(cfg, out)
    assert read_status(done)["status"] == "complete" and (done / "metrics.json").is_file()
    assert dense.stat().st_mtime_ns == before  # the app's stage, reused by the run
    assert prepare_config(cfg, out) == out  # a finished run opens as it is
    assert read_status(out)["status"] == "complete"
