"""Issue 33: a run folder owns only its own files; one run at a time per folder; sweep
labels unique; temp files unique beside the target. Each test fails on the old code."""

import dataclasses
import json
import os
import subprocess
import sys
import types

import numpy as np
import pytest

from fxspace.config import expand_sweep
from fxspace.pipelines import _REGISTERED, register, run_dict
from fxspace.runs import (
    LOCK,
    MANIFEST,
    RunLockedError,
    manifest_files,
    run_lock,
    save_npz_atomic,
)


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n: int = 2

    def validate(self):
        pass


def _toy_run(cfg, run_dir, seed):
    save_npz_atomic(run_dir / "expression_space.npz", x=np.arange(cfg.n))
    return {"sq": cfg.n**2}


@pytest.fixture
def toy():
    mod = types.ModuleType("safety_toy")
    mod.Config, mod.STAGES, mod.run = _Cfg, (), _toy_run
    register(mod, "safety_toy")
    yield "safety_toy"
    _REGISTERED.pop("safety_toy", None)


def test_force_on_parent_leaves_nested_runs_intact(tmp_path, toy):
    R = tmp_path / "R"
    (nested,) = run_dict({"experiment": toy, "n": 3}, R / "important")
    before = sorted(p.name for p in nested.iterdir())
    run_dict({"experiment": toy, "n": 4}, R, force=True)
    run_dict({"experiment": toy, "n": 5}, R, force=True)
    assert sorted(p.name for p in nested.iterdir()) == before
    assert json.loads((nested / "metrics.json").read_text())["sq"] == 9
    assert json.loads((R / "metrics.json").read_text())["sq"] == 25


def test_clean_never_deletes_a_nested_runs_file_even_if_listed(tmp_path, toy):
    from fxspace.runs import clean_run

    (nested,) = run_dict({"experiment": toy, "n": 3}, tmp_path / "R" / "sub")
    (tmp_path / "R" / MANIFEST).write_text("sub/metrics.json\n")  # a stray listing
    clean_run(tmp_path / "R")
    assert (nested / "metrics.json").is_file()


def test_fresh_run_refuses_to_overwrite_a_users_file(tmp_path, toy):
    U = tmp_path / "U"
    U.mkdir()
    (U / "expression_space.npz").write_bytes(b"the user's")
    with pytest.raises(FileExistsError, match=r"expression_space\.npz.*did not write"):
        run_dict({"experiment": toy}, U)
    assert (U / "expression_space.npz").read_bytes() == b"the user's"
    assert "expression_space.npz" not in manifest_files(U)


def test_sweep_labels_unique_when_values_collide(tmp_path, toy):
    raw = {"experiment": "x", "data": {"paths": []},
           "sweep": {"data.paths": [["x/a.c3d"], ["x-a.c3d"]]}}  # fmt: skip
    labels = [lab for lab, _ in expand_sweep(raw)]
    assert len(set(labels)) == 2
    raw2 = {"experiment": toy, "sweep": {"n": [2, 3]}}
    assert [lab for lab, _ in expand_sweep(raw2)] == ["n=2", "n=3"]  # no collision: as before


def test_lock_refuses_a_second_holder_and_takes_over_a_dead_one(tmp_path, toy):
    d = tmp_path / "CE"
    code = (
        "import sys, time; from fxspace.runs import run_lock\n"
        f"with run_lock({str(d)!r}):\n    print('held', flush=True); time.sleep(30)\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "held"
        with pytest.raises(RunLockedError, match=rf"pid {p.pid}.*delete the lock file"):
            with run_lock(d, wait=0.5):
                pass
        with pytest.raises(RunLockedError, match="another process"):
            run_dict({"experiment": toy}, d)  # a second `fxspace run --out CE` refuses
        assert not (d / "metrics.json").exists()
    finally:
        p.kill()
        p.wait()
        p.stdout.close()
    assert (d / LOCK).is_file()  # the holder died holding it
    with run_lock(d, wait=0):  # stale: taken over
        assert json.loads((d / LOCK).read_text())["pid"] == os.getpid()
    assert not (d / LOCK).exists()
    (r,) = run_dict({"experiment": toy}, d)
    assert json.loads((r / "metrics.json").read_text())["sq"] == 4


def test_second_config_after_the_first_finished_is_refused_not_mixed(tmp_path, toy):
    d = tmp_path / "CE"
    run_dict({"experiment": toy, "n": 3}, d)
    from fxspace.config import ConfigError

    with pytest.raises(ConfigError, match="different config"):
        run_dict({"experiment": toy, "n": 4}, d)
    assert json.loads((d / "metrics.json").read_text())["sq"] == 9


def test_write_gltf_morph_never_touches_name_dot_tmp(tmp_path):
    from fxspace.io import read_gltf_morph, write_gltf_morph

    (tmp_path / "user.glb.tmp").write_bytes(b"mine")
    V = np.random.default_rng(0).normal(size=(3, 4, 3)).astype(np.float32)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    write_gltf_morph(tmp_path / "user.glb", V, F, 30.0)
    assert (tmp_path / "user.glb.tmp").read_bytes() == b"mine"
    assert np.allclose(read_gltf_morph(tmp_path / "user.glb").vertices, V, atol=1e-5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["user.glb", "user.glb.tmp"]


def test_writers_accept_a_255_character_name(tmp_path):
    from fxspace.io import MarkerSequence, read_markers, write_trc

    name = "m" * 251 + ".trc"
    assert len(name) == 255
    seq = MarkerSequence(np.zeros((2, 1, 3)) + 1.0, ["a"], 60.0, "mm")
    p = write_trc(tmp_path / name, seq)
    assert np.allclose(read_markers(p).positions, 1.0)


def test_user_state_is_never_in_the_manifest_nor_cleaned(tmp_path):
    from fxspace.runs import active_run, clean_run, unrecorded, write_json_atomic

    with active_run(tmp_path):
        write_json_atomic(tmp_path / "metrics.json", {"a": 1})
        with unrecorded():
            write_json_atomic(tmp_path / "edits.json", {"keys": []})
    assert manifest_files(tmp_path) == ["metrics.json"]
    (tmp_path / MANIFEST).write_text("metrics.json\nedits.json\n")  # an older run's manifest
    clean_run(tmp_path)
    assert (tmp_path / "edits.json").is_file() and not (tmp_path / "metrics.json").exists()
