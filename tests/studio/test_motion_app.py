"""The live motion controller: the controller without a browser, then the real page in
headless Chromium (skipped, with the reason, where viser, playwright or Chromium is absent).
Synthetic spaces (a small skeleton, random smooth clips) keep it independent of the data."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TOY_NAMES as NAMES
from helpers import TOY_OFFSETS as OFFSETS
from helpers import TOY_PARENTS as PARENTS
from helpers import toy_clips as _clips

import fxspace as fx
from fxspace import motion as M
from fxspace.studio import MotionController
from fxspace.studio._motion_scene import body_mesh


def _setup(upper_joint):
    rng = np.random.default_rng(1)
    qL, rL = _clips(rng, 4, 20, 0.4)
    qU, rU = _clips(rng, 2 if upper_joint < 0 else 5, 16, 0.6)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.7, 0.9, 0.8, 1.0)[: len(qU)]])
    sp = M.build_spaces(
        M.stack_examples(list(qL), list(rL), wl), M.stack_examples(list(qU), list(rU), wu),
        np.linspace(0, 15, 20), PARENTS, OFFSETS, mask=M.upper_body_mask(PARENTS, NAMES),
        spine=4, lower_joint=3, lower_dims=(0, 2), lower_time=19.0, upper_joint=upper_joint,
        upper_time=8.0, key=jax.random.PRNGKey(0), n_samples=60, knn_k=4, k_replace=5,
    )  # fmt: skip
    skel = fx.motion.Motion(
        names=NAMES, parents=PARENTS, offsets=OFFSETS, root_translation=np.zeros((1, 3)),
        rotations=np.tile([1.0, 0, 0, 0], (1, len(NAMES), 1)), rate=30.0,
        channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation",
                   "Xrotation"),) + (("Zrotation", "Yrotation", "Xrotation"),) * 7,
    )  # fmt: skip
    return M.Setup("mood_walk" if upper_joint < 0 else "block_walk", sp, skel, 1.0, (3, 3),
                   [], [], {})  # fmt: skip


@pytest.fixture(scope="module")
def mood():
    return _setup(-1)


def test_controller_plays_records_and_follows_the_controls(mood, tmp_path):
    ctl = MotionController(mood)
    r0 = ctl.rotations.copy()
    ctl.start_recording()
    for _ in range(5):
        ctl.step()
    assert ctl.frame == 5 and float(ctl.state.synth.t_lower) > 0
    # the joy weight changes the upper body (joint 7 copies the upper blend)
    st = ctl.state
    ctl.set_joy(0.0)
    ctl.step()
    a = ctl.rotations.copy()
    ctl.state = st
    ctl.set_joy(1.0)
    ctl.step()
    assert np.abs(ctl.rotations[7] - a[7]).max() > 1e-3
    assert np.abs(ctl.rotations - r0).max() > 1e-3
    # the foot target is the lower parameter (x, z)
    ctl.set_foot_target([0.3, 0.0, 1.1])
    np.testing.assert_allclose(ctl.lower_param, [0.3, 1.1])
    np.testing.assert_allclose(ctl.foot_target_world(), [0.3, 0.0, 1.1])
    out = ctl.stop_recording(tmp_path / "rec.bvh")
    m = fx.io.read_bvh(out)
    assert m.num_frames == 7 and m.names == NAMES
    # continuous locomotion: the clocks wrap, the walker walks on without jumping back
    roots = []
    for _ in range(60):
        ctl.step()
        roots.append(ctl.root.copy())
    assert float(ctl.state.cycles) >= 1
    assert float(ctl.state.synth.t_lower) < ctl.sp.lam.shape[0] - 1
    step = np.linalg.norm(np.diff(np.asarray(roots)[:, [0, 2]], axis=0), axis=1)
    assert step.max() <= 3.0 * np.median(step)


def test_hand_target_round_trip_and_samples_move():
    ctl = MotionController(_setup(7))
    target = ctl.hand_target_world() + np.asarray([0.05, 0.02, 0.0])
    ctl.set_hand_target(target)
    np.testing.assert_allclose(ctl.hand_target_world(), target, atol=1e-9)
    up0 = ctl.upper_samples_world().copy()
    ctl.set_foot_target(ctl.lower_samples_world()[2])
    ctl.step()
    assert np.abs(ctl.upper_samples_world() - up0).max() > 1e-4  # re-placed (paper Fig. 2)


def test_steering_turns_the_walker(mood):
    """Turning left (+) vs right (−) from the same start: the headings part ways."""
    yaws = {}
    for sign in (+1, -1):
        ctl = MotionController(mood)
        lo, hi = ctl.turn_range()
        assert lo < 0 < hi or lo < hi  # the toy examples turn a little both ways
        ctl.set_turn(hi if sign > 0 else lo)
        for _ in range(40):
            ctl.step()
        yaws[sign] = float(ctl.state.yaw)
    assert yaws[+1] > yaws[-1]
    V, F = body_mesh(ctl.joints(), ctl.skel.parents)
    assert V.shape[1] == 3 and F.max() < len(V) and np.isfinite(V).all()
    assert len(ctl.contacts()) == 2


@pytest.mark.browser
def test_browser_steers_the_walker(mood, chromium):
    from fxspace.studio import serve_motion
    from fxspace.studio._server import ServeOptions

    opts = ServeOptions(port=0, block=False, environment_map=False)
    server, ctl = serve_motion(mood, playing=False, options=opts)
    with chromium.page(server, viewport={"width": 1200, "height": 800}) as page:
        page.get_by_text("mood_walk", exact=False).first.wait_for(timeout=60_000)
        lo, hi = ctl.turn_range()
        page.get_by_role("button", name="◀ Left").click()
        page.get_by_text("turn +", exact=False).first.wait_for(timeout=60_000)
        assert ctl.turn == pytest.approx(min(hi, 0.1 * (hi - lo)), abs=1e-6)
        box = chromium.field(page, "Turn").last
        box.fill(f"{lo:.1f}")
        box.press("Enter")
        for _ in range(100):  # the typed value arrives (and settles: no later events)
            if abs(ctl.turn - max(lo, round(lo, 1))) < 0.6:
                break
            page.wait_for_timeout(100)
        page.wait_for_timeout(300)
        assert ctl.turn == pytest.approx(max(lo, round(lo, 1)), abs=0.6)
        y0 = float(ctl.state.yaw)
        left = MotionController(mood)  # the same walker steered fully left
        left.set_turn(hi)
        for _ in range(30):
            ctl.step()
            left.step()
        # steered to the right of the left-steered twin (the toy clips' own heading drift
        # within a cycle moves both; the steering is the difference)
        assert float(ctl.state.yaw) - y0 < float(left.state.yaw) - y0 - 0.1
        # the body is drawn as a shaded mesh, not a stick figure
        page.get_by_text("Parameter spaces", exact=False).first.wait_for(timeout=60_000)


@pytest.mark.browser
def test_browser_slider_changes_the_pose(mood, tmp_path, chromium):
    from fxspace.studio import serve_motion

    server, ctl = serve_motion(
        mood, port=0, environment_map=False, block=False, playing=False,
        export_path=tmp_path / "rec.bvh",
    )  # fmt: skip
    with chromium.page(server, viewport={"width": 1200, "height": 800}) as page:
        page.get_by_text("mood_walk", exact=False).first.wait_for(timeout=60_000)
        ctl.step()  # mid-clip, where the examples differ
        joy0 = float(ctl.upper_param()[0])
        box = chromium.field(page, "Joy").last
        box.fill("0.95")
        box.press("Enter")
        page.get_by_text("joy 0.95", exact=False).wait_for(timeout=60_000)
        assert ctl.joy == pytest.approx(0.95)
        for _ in range(20):  # the controls are followed with a short lag
            ctl.step()
        assert float(ctl.upper_param()[0]) > joy0 + 0.3  # the upper blend followed
        page.get_by_role("button", name="Record").click()
        page.get_by_text("recording", exact=False).first.wait_for(timeout=60_000)
        ctl.step()
        ctl.step()
        page.get_by_role("button", name="Stop and write BVH").click()
        page.get_by_text("wrote 2 frames", exact=False).wait_for(timeout=60_000)
    assert fx.io.read_bvh(tmp_path / "rec.bvh").num_frames == 2
    assert jnp.isfinite(jnp.asarray(ctl.rotations)).all()


def test_bone_instances_place_a_unit_cylinder_on_every_bone():
    """The per-frame update (three small arrays) puts the unit cylinder's axis exactly on
    each bone, its rim at the limb radius, whatever the bone's direction (−z included)."""
    from scipy.spatial.transform import Rotation

    from fxspace.studio._motion_scene import _bones, bone_instances

    rng = np.random.default_rng(0)
    X = rng.normal(size=(8, 3))
    parents = [-1, 0, 1, 2, 0, 4, 5, 0]
    X[7] = X[0] + [0.0, 0.0, -0.5]  # a bone along −z (the quaternion's singular case)
    q, p, s = bone_instances(X, parents, radius=0.05)
    pi, ji = _bones(parents)
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]].astype(np.float64))  # scipy: xyzw
    np.testing.assert_allclose(R.apply(s * [0.0, 0.0, 1.0]) + p, X[ji], atol=1e-6)
    rim = R.apply(s * [1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.linalg.norm(rim, axis=1), 0.05, rtol=1e-6)
    np.testing.assert_allclose(np.sum(rim * (X[ji] - X[pi]), axis=1), 0.0, atol=1e-6)
    V, _ = body_mesh(X, parents, radius=0.05)  # the same limbs as the old per-frame mesh
    base_centres = V.reshape(len(ji), 2, -1, 3)[:, 0].mean(1)
    np.testing.assert_allclose(base_centres, X[pi], atol=1e-6)


def test_run_folder_setup_is_read_not_rebuilt_and_never_another_configs(tmp_path, monkeypatch):
    """``fxspace studio RUN_DIR`` reads the run's stored set-up (no rebuild) when the cache
    is bound to the folder's config; an edited config.toml gets its own set-up built."""
    import os

    from fxspace.pipelines import parametric_synthesis as ps
    from fxspace.runs import run_key
    from fxspace.studio._motion import load_setup

    st = _setup(5)
    text = 'experiment = "parametric_synthesis"\nsetups = ["block_walk"]\n'
    cfg = tmp_path / "config.toml"
    cfg.write_text(text)
    (tmp_path / "cache").mkdir()
    np.savez(tmp_path / "cache" / "block_walk_setup.npz", **ps._setup_to_arrays(st))
    (tmp_path / "cache" / "KEY").write_text(run_key(text, []) + "\n")
    monkeypatch.setattr(ps, "data_files", lambda cfg: [])  # no clips needed for this test

    def rebuilt(*a, **k):
        raise AssertionError("the stored set-up was rebuilt")

    monkeypatch.setattr(M, "prepare_setup", rebuilt)
    got = load_setup(tmp_path)
    assert got.name == "block_walk" and got.skeleton.names == st.skeleton.names
    np.testing.assert_allclose(got.spaces.upper_params, st.spaces.upper_params, rtol=1e-6)
    np.testing.assert_allclose(got.spaces.lam, st.spaces.lam, rtol=1e-6)
    cfg.write_text(text + "stride = 2\n")  # another config: the stored stage is not served
    os.utime(cfg, ns=(cfg.stat().st_atime_ns, cfg.stat().st_mtime_ns + 10**9))
    calls = []
    monkeypatch.setattr(M, "prepare_setup", lambda *a, **k: calls.append(a[0]) or st)
    load_setup(tmp_path)
    assert calls == ["block_walk"]


def test_run_key_covers_every_clip_of_every_setup(data_dir):
    """The parametric-synthesis run key (and so its stored set-ups) covers the clips read:
    Bandai BVH files and CMU ASF + AMC files of every configured set-up; a missing clip
    is named."""
    from fxspace.pipelines import parametric_synthesis as ps

    cfg = ps.Config(setups=("mood_walk", "block_kick"))
    names = [p.name for p in ps.data_files(cfg)]
    assert "dataset-1_walk_happy_001.bvh.gz" in names and "dataset-1_walk_sad_001.bvh.gz" in names
    assert "135.asf" in names and "135_04.amc.gz" in names and "135_09.amc.gz" in names
    assert len(names) == len(set(names))  # the subject's ASF once
    lower, upper = M.setup_takes("block_kick")
    assert lower == ("135_04", "135_07", "135_11") and upper == ("135_05", "135_10", "135_09")
    custom = ps.Config(setups=("mood_walk",), data=M.SetupData(lower=("dataset-x",)))
    with pytest.raises(fx.errors.DataNotFoundError, match="dataset-x.bvh.gz"):
        ps.data_files(custom)
