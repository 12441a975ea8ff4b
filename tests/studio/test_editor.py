"""The control-point editor: the controller without a browser (keys, replay after a restart,
undo, modes, re-fit, export), then the real page in headless Chromium (skipped, with the
reason, where viser, playwright or Chromium is absent)."""

import json
import re

import jax
import numpy as np
import pytest
from helpers import face_like

import fxspace as fx
from fxspace.studio import (
    EditorController,
    EditorData,
    load_editor_data,
    save_editor_data,
)


@pytest.fixture(scope="module")
def scene_data():
    _, pos = face_like(n=40, m=12, seed=3)
    surf = fx.face_surface(pos[0], 200)
    X = np.asarray(fx.rbf_deform(surf.vertices, pos[0], pos))
    fit = fx.fit_scene(X, 4, boundaries=[0, 13, 26, 39], key=jax.random.PRNGKey(0), n_init=3)
    return X, surf.faces, fit.model


@pytest.fixture
def run_dir(scene_data, tmp_path):
    X, faces, scene = scene_data
    save_editor_data(tmp_path, EditorData(X, faces, scene, rate=30.0, gamma=0.5))
    return tmp_path


def test_edit_is_saved_and_replayed_after_a_restart(run_dir, scene_data):
    X, _, scene = scene_data
    ctl = EditorController(load_editor_data(run_dir))
    np.testing.assert_array_equal(ctl.sequence("original"), X.astype(np.float32))
    lin = np.asarray(fx.linear_scene(X.astype(np.float32), scene.boundaries))
    np.testing.assert_allclose(ctl.sequence("linear"), lin, rtol=1e-5, atol=1e-4)
    ctl.set_frame(13)  # a boundary frame is a stored key frame: no edit there
    assert not ctl.move_control(0, [0.0, 0.0, 0.0]) and "boundary" in ctl.message
    ctl.set_frame(5)
    seg, C = ctl.controls()
    assert seg == 0
    target = C[1] + [4.0, -2.0, 1.0]
    preview = ctl.preview(1, target)
    assert ctl.move_control(1, target)
    assert (run_dir / "edits.json").is_file()
    ed, model = ctl.sequence("edited"), ctl.sequence("control points")
    np.testing.assert_allclose(ctl.vertices(), preview, atol=1e-4)  # live view = the key
    W = np.asarray(scene.segments[0].weights[:, 1])
    moved = np.abs(ed - model).max(axis=(0, 2)) > 1e-5
    np.testing.assert_array_equal(moved, W > 0)  # the region follows through the weights
    np.testing.assert_allclose(ed[5] - model[5], W[:, None] * [4.0, -2.0, 1.0], atol=1e-4)
    np.testing.assert_array_equal(ed[13:], model[13:])  # other segments and the boundary
    _, C2 = ctl.controls()
    np.testing.assert_allclose(C2[1], target, atol=1e-9)
    assert ctl.nudge_control(2, [0.0, 1.0, 0.0]) and len(ctl.keys) == 2
    saved = ctl.sequence("edited").copy()
    # restart: a new controller on the run folder replays the same frames
    again = EditorController(load_editor_data(run_dir))
    assert again.keys == ctl.keys and "replayed 2" in again.message
    np.testing.assert_array_equal(again.sequence("edited"), saved)
    again.undo()
    again.undo()
    np.testing.assert_array_equal(again.sequence("edited"), again.sequence("control points"))
    assert EditorController(load_editor_data(run_dir)).keys == []
    # an edits file for another segmentation is not replayed
    fx.save_edits(run_dir / "edits.json", ctl.keys, boundaries=[0, 20, 39])
    assert "another segmentation" in EditorController(load_editor_data(run_dir)).message


def test_play_modes_export_and_refit(run_dir, tmp_path):
    pygltflib = pytest.importorskip("pygltflib")
    ctl = EditorController(load_editor_data(run_dir))
    ctl.loop = False
    for _ in range(ctl.n_frames + 1):
        ctl.step()
    assert ctl.frame == ctl.n_frames - 1 and not ctl.playing
    for mode in ("original", "linear", "control points", "edited"):
        ctl.set_mode(mode)
        assert f"Showing: {mode}" in ctl.status()
    with pytest.raises(fx.FxspaceError, match="mode"):
        ctl.set_mode("wireframe")
    ctl.set_frame(20)
    _, C = ctl.controls()
    ctl.move_control(0, C[0] + [1.0, 1.0, 1.0])
    out = tmp_path / "export"
    paths = ctl.export(out, "gltf")
    g = pygltflib.GLTF2().load(str(out / "edited.glb"))
    prim = g.meshes[0].primitives[0]
    assert len(prim.targets) == ctl.n_frames
    assert g.animations[0].channels[0].target.path == "weights"
    blob = g.binary_blob()
    acc = g.accessors[prim.targets[20]["POSITION"] if isinstance(prim.targets[20], dict)
                      else prim.targets[20].POSITION]  # fmt: skip
    view = g.bufferViews[acc.bufferView]
    d = np.frombuffer(blob, "<f4", acc.count * 3, view.byteOffset).reshape(-1, 3)
    V = ctl.sequence("edited")
    np.testing.assert_allclose(d, V[20] - V[0], atol=1e-4)
    assert {p.name for p in paths} >= {"edited.glb", "control_points.npz", "edits.json"}
    assert len(ctl.export(out, "obj")) == ctl.n_frames + 2
    assert len(list((out / "ply").glob("*.ply"))) == 0
    ctl.export(out, "ply")
    assert len(list((out / "ply").glob("*.ply"))) == ctl.n_frames
    ctl.refit(2, 3, 0.5)
    assert len(ctl.data.scene.boundaries) == 3 and ctl.keys == []
    assert (run_dir / "editor_scene.npz").is_file()
    assert len(load_editor_data(run_dir).scene.boundaries) == 3
    assert json.loads((run_dir / "edits.json").read_text())["keys"] == []


@pytest.mark.browser
def test_browser_editor_moves_a_control_point(run_dir, chromium):
    from fxspace.studio import serve_editor

    server, ctl = serve_editor(
        load_editor_data(run_dir), port=0, environment_map=False, block=False
    )
    with chromium.page(server, viewport={"width": 1200, "height": 800}) as page:
        page.get_by_text("Edit keys: 0").wait_for(timeout=60_000)

        frame = chromium.field(page, "Frame").last
        frame.fill("5")
        frame.press("Enter")
        page.get_by_text("Frame 5", exact=True).wait_for(timeout=60_000)
        before = ctl.sequence("edited")[5].copy()
        chromium.field(page, "Control point").first.fill("1")
        offs = chromium.field(page, "Offset")
        offs.nth(0).fill("0.3")
        offs.nth(1).fill("0.2")
        offs.nth(1).press("Tab")
        page.wait_for_timeout(500)
        page.get_by_role("button", name="Move control point").click()
        page.get_by_text("Edit keys: 1").wait_for(timeout=60_000)
        k = ctl.keys[-1]
        assert (k.segment, k.control, k.frame) == (0, 1, 5)
        after = ctl.sequence("edited")[5]
        assert np.abs(after - before).max() > 1e-3  # the face changed
        shown = page.get_by_text("Edited vs model here:", exact=False).inner_text()
        assert float(re.search(r"Edited vs model here: ([0-9.]+)", shown)[1]) > 0
        page.get_by_role("button", name="Undo edit").click()
        page.get_by_text("Edit keys: 0").wait_for(timeout=60_000)
    assert json.loads((run_dir / "edits.json").read_text())["keys"] == []


def test_studio_dispatches_on_the_experiment(tmp_path, capsys):
    from fxspace import studio
    from fxspace.cli import main
    from fxspace.studio._editor import serve as serve_editor_app
    from fxspace.studio._navigator import serve as serve_navigator_app

    assert studio.app_for("reconstruction") is serve_editor_app
    assert studio.app_for("navigation") is serve_navigator_app
    cfg = tmp_path / "ik.toml"
    cfg.write_text('experiment = "no_such_app"\n')
    assert studio.experiment_of(cfg) == "no_such_app"
    for cmd in ("studio", "view"):  # view is kept as an alias
        assert main([cmd, str(cfg)]) == 2
        err = capsys.readouterr().err
        assert "no studio app for experiment 'no_such_app'" in err and "reconstruction" in err
    with pytest.raises(fx.FxspaceError, match="run the reconstruction"):
        load_editor_data(tmp_path)
