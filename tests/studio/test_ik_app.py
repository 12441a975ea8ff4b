"""The IK studio: the controller without a browser, then the real page in headless
Chromium (skipped, with the reason, where viser, playwright or Chromium is absent)."""

import time

import numpy as np
import pytest

import fxspace as fx
from fxspace.studio import IKController


@pytest.fixture(scope="module")
def mesh(data_dir):
    return fx.io.read_gltf(data_dir / "mesh" / "RiggedSimple.glb")


def _front_triangles(ctl, k, seed=0):
    vis = np.flatnonzero(ctl.visible((0.0, 0.0, -1.0)))
    return np.random.default_rng(seed).choice(vis, k, replace=False)


def test_controller_markers_drag_and_track(mesh, tmp_path):
    ctl = IKController(mesh, mesh.animation_names[0])
    tris = _front_triangles(ctl, 3)
    for t in tris:
        ctl.add_marker(int(t), view_dir=(0.0, 0.0, -1.0))
    assert ctl.num_markers == 3
    back = int(np.flatnonzero(~ctl.visible((0.0, 0.0, -1.0)))[0])
    with pytest.raises(fx.FxspaceError, match="faces away"):
        ctl.add_marker(back, view_dir=(0.0, 0.0, -1.0))
    with pytest.raises(fx.FxspaceError, match="already holds"):
        ctl.add_marker(int(tris[0]))
    # drag marker 0's target sideways: the marker follows, the mesh moves
    v0 = ctl.vertices.copy()
    p0 = ctl.marker_points()[0]
    size = float(np.ptp(mesh.vertices, axis=0).max())
    goal = p0 + np.array([0.1 * size, 0.0, 0.0])
    ctl.move_target(0, goal)
    assert np.linalg.norm(ctl.marker_points()[0] - goal) < 0.5 * np.linalg.norm(p0 - goal)
    assert np.abs(ctl.vertices - v0).max() > 1e-3 * size
    # a click ray straight down -z onto a visible triangle's centre adds a marker there
    # (the free visible triangle with the front-most centre: nothing lies in front of it)
    free = [t for t in np.flatnonzero(ctl.visible((0.0, 0.0, -1.0))) if t not in ctl.triangles]
    centres = ctl.vertices[ctl.faces[free]].mean(1)
    c = centres[np.argmax(centres[:, 2])]
    k = ctl.pick(c + np.array([0, 0, 10.0 * size]), (0.0, 0.0, -1.0))
    assert k == 3 and np.linalg.norm(ctl.marker_points()[3] - c) < 1e-4 * size
    assert ctl.pick(c + np.array([100.0 * size, 0, 0]), (0.0, 0.0, -1.0)) is None
    ctl.remove_marker(3)
    assert ctl.num_markers == 3
    # track two animation frames with the current markers, then export them as BVH
    ctl.set_time(0.5)
    ctl.step()
    assert len(ctl.recorded) == 2 and float(ctl.last_result.residual) < 0.05 * size
    out = ctl.export_bvh(tmp_path / "track.bvh")
    mot = fx.io.read_bvh(out)
    assert mot.num_frames == 2 and mot.num_joints == mesh.num_joints
    # ... and as glTF: the re-read animation's last frame is the mesh on screen
    back = fx.io.read_gltf(ctl.export_gltf(tmp_path / "track.glb"))
    assert back.animation_range("fxspace") == pytest.approx((0.0, 1.0 / ctl.fps))
    last = fx.mesh.animation_vertices(back, "fxspace", [1.0 / ctl.fps])[0]
    np.testing.assert_allclose(last, ctl.vertices, atol=1e-4 * size)


def test_controller_floor_and_normal_constraints(mesh):
    """A floor constraint puts its marker on the floor plane while a dragged target pulls
    the others; a normal constraint keeps its marker's surface normal; removing a marker
    renumbers the constraints."""
    ctl = IKController(mesh, None)
    tris = _front_triangles(ctl, 3, seed=1)
    for t in tris:
        ctl.add_marker(int(t), view_dir=(0.0, 0.0, -1.0))
    size = float(np.ptp(mesh.vertices, axis=0).max())
    ctl.floor_height = float(ctl.marker_points()[0, 1]) - 0.05 * size
    ctl.add_constraint(0, "floor")
    from fxspace.studio._ik import status_text

    assert ctl.status()["constraints"] == {0: "floor"}
    assert "Constraints: 0: floor" in status_text(ctl.status())
    y0 = float(ctl.marker_points()[0, 1])
    assert abs(y0 - ctl.floor_height) < 1e-3 * size
    n_before = ctl._current_normals()[1]
    ctl.add_constraint(1, "normal")
    ctl.move_target(2, ctl.marker_points()[2] + np.array([0.05 * size, 0.0, 0.0]))
    assert abs(float(ctl.marker_points()[0, 1]) - ctl.floor_height) < 1e-3 * size
    assert float(np.dot(ctl._current_normals()[1], n_before)) > 0.99
    cons, tn = ctl.ik_constraints()
    assert cons.contact is not None and cons.normal is not None and tn.shape == (1, 3)
    ctl.remove_marker(0)
    assert ctl.constraints == {0: "normal"}
    ctl.add_constraint(0, "none")
    assert ctl.ik_constraints() == (None, None)
    with pytest.raises(fx.FxspaceError, match="kind must be"):
        ctl.add_constraint(0, "ceiling")


@pytest.mark.browser
def test_browser_ik_studio(mesh, tmp_path, chromium):
    from fxspace.studio import serve_ik

    server, ctl = serve_ik(
        mesh, port=0, environment_map=False, block=False, export_path=tmp_path / "pose.bvh"
    )
    tris = _front_triangles(ctl, 2)
    size = float(np.ptp(mesh.vertices, axis=0).max())
    with chromium.page(server) as page:
        page.get_by_text("Markers: 0").wait_for(timeout=60_000)

        for i, t in enumerate(tris):
            chromium.field(page, "Triangle").fill(str(int(t)))
            page.get_by_role("button", name="Add marker").click()
            page.get_by_text(f"Markers: {i + 1}").wait_for(timeout=60_000)
        assert ctl.triangles == [int(t) for t in tris]
        p0 = ctl.marker_points()[1].copy()
        v0 = ctl.vertices.copy()
        goal = p0 + np.array([0.0, 0.1 * size, 0.0])
        # a text box reaches the server a moment after it is typed into: retry the
        # click until the controller has the target (the first solve also compiles)
        for _ in range(10):
            chromium.field(page, "Marker").fill("1")
            chromium.field(page, "Target x y z").fill(" ".join(f"{x:.6f}" for x in goal))
            page.wait_for_timeout(300)
            page.get_by_role("button", name="Move target").click()
            deadline = time.monotonic() + 180.0
            while time.monotonic() < deadline and not (
                "solved in" in ctl.message or "three numbers" in ctl.message
            ):
                time.sleep(0.1)
            if "solved in" in ctl.message:  # "<solver>: solved in N steps, ..."
                break
        page.get_by_text("solved in", exact=False).wait_for(timeout=60_000)
        p1 = ctl.marker_points()[1]
        assert np.linalg.norm(p1 - goal) < 0.5 * np.linalg.norm(p0 - goal)
        moved = np.linalg.norm(ctl.vertices - v0, axis=1)
        assert moved.max() > 1e-3 * size
        page.get_by_role("button", name="Export BVH").click()
        page.get_by_text("wrote 1 frame", exact=False).wait_for(timeout=60_000)
        page.get_by_role("button", name="Export glTF").click()
        page.get_by_text("pose.glb", exact=False).wait_for(timeout=60_000)
    assert (tmp_path / "pose.bvh").is_file()
    back = fx.io.read_gltf(tmp_path / "pose.glb")  # the pose on screen, as an animated glTF
    np.testing.assert_allclose(
        fx.mesh.animation_vertices(back, "fxspace", [0.0])[0], ctl.vertices, atol=1e-4 * size
    )


def test_studio_opens_a_mesh_ik_config_without_running_it(data_dir, tmp_path, monkeypatch):
    """``fxspace studio configs/mesh_ik.toml`` builds only what the app shows (one mesh):
    the five-model experiment is not run first (issue 31.9), and a ``.glb`` opens as it
    is (it used to be read as a TOML)."""
    from pathlib import Path

    import fxspace.pipelines as pipelines
    from fxspace.cli import studio_target
    from fxspace.studio import experiment_of, load_ik_mesh, opens_directly

    def boom(*a, **k):
        raise AssertionError("the mesh_ik experiment must not run before the app opens")

    import fxspace.pipelines._commands as commands

    # the front's names (what the command line calls) and the module that runs configs
    for mod, name in ((pipelines, "run_config"), (pipelines, "prepare_config"),
                      (commands, "run_config")):
        monkeypatch.setattr(mod, name, boom)
    cfg = Path(__file__).resolve().parents[2] / "configs" / "mesh_ik.toml"
    assert opens_directly(cfg)
    assert studio_target(cfg, tmp_path / "run") == cfg
    assert not (tmp_path / "run").exists()
    mesh, anim = load_ik_mesh(cfg)
    assert mesh.num_joints > 1 and anim == "Anim_0"
    glb = data_dir / "mesh" / "RiggedSimple.glb"
    assert experiment_of(glb) == "mesh_ik" and studio_target(glb) == glb
    # a config of an experiment whose app needs its run is still run first
    nav = cfg.with_name("navigation.toml")
    assert not opens_directly(nav)
