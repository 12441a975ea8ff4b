"""Issue 48.2: the walker wears a skinned character (live retargeting + LBS each frame),
the capsule body an option; the turn slider's ends rounded. No browser: the scene nodes
are checked on the server side."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import numpy as np
import pytest

import fxspace as fx

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "mesh"))
from mesh_toys import branching_mesh  # noqa: E402


class _Ctl:
    """The bits of a MotionController that `_Body` reads: a skeleton walking along x."""

    def __init__(self, motion):
        self.skel = motion
        self.x = np.asarray(fx.motion.forward_kinematics(motion))
        self.frame = 0
        self.setup = types.SimpleNamespace(feet=(0,))

    def joints(self):
        return self.x[self.frame % len(self.x)]

    def contacts(self):
        return [True]

    def upper_samples_world(self):
        return None


def test_body_wears_the_character_and_capsules_are_an_option():
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    from fxspace.studio._motion import _Body
    from fxspace.studio._server import new_server

    mesh = branching_mesh(3)
    rng = np.random.default_rng(0)
    n = 6
    rot = np.tile([1.0, 0, 0, 0], (n, mesh.num_joints, 1))
    rot[:, 1:] += rng.normal(0, 0.2, (n, mesh.num_joints - 1, 4))
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
    off = np.asarray(mesh.rest_translations)
    motion = fx.motion.Motion(
        names=mesh.joint_names, parents=tuple(int(p) for p in mesh.parents), offsets=off,
        root_translation=np.linspace([0, 0, 0], [1.0, 0, 0], n), rotations=rot, rate=30.0,
        channels=((),) * mesh.num_joints,
    )  # fmt: skip
    ctl = _Ctl(motion)
    server = new_server(0)
    try:
        body = _Body(server, ctl, fx.mesh.live_retarget(motion, mesh))
        body.show_capsules(False)
        assert body.skin.visible and not body.limbs.visible
        v0 = np.asarray(body.skin.vertices).copy()
        ctl.frame = 3
        body.draw(False)
        v1 = np.asarray(body.skin.vertices)
        assert v1.shape == v0.shape and np.abs(v1 - v0).max() > 1e-3  # the skin moved
        assert body.center[0] > v0.mean(0)[0]  # and travelled with the root
        body.show_capsules(True)
        assert body.limbs.visible and not body.skin.visible
    finally:
        server.stop()


@pytest.mark.slow
def test_recording_exports_the_character_as_gltf(tmp_path):
    from fxspace.studio._motion import export_character_gltf

    mesh = branching_mesh(3)
    rng = np.random.default_rng(1)
    n = 12
    rot = np.tile([1.0, 0, 0, 0], (n, mesh.num_joints, 1))
    rot[:, 1:] += np.cumsum(rng.normal(0, 0.03, (n, mesh.num_joints - 1, 4)), axis=0)
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
    root = np.linspace([0, 0, 0], [0.5, 0, 0], n)
    skel = fx.motion.Motion(
        names=mesh.joint_names, parents=tuple(int(p) for p in mesh.parents),
        offsets=np.asarray(mesh.rest_translations), root_translation=root[:1],
        rotations=rot[:1], rate=30.0, channels=((),) * mesh.num_joints,
    )  # fmt: skip
    lr = fx.mesh.live_retarget(skel, mesh)
    glb = export_character_gltf(skel, list(zip(rot, root, strict=True)), lr, tmp_path / "s.bvh")
    assert glb == tmp_path / "s.glb"
    back = fx.io.read_gltf(glb)
    v = fx.mesh.animation_vertices(back, 0, np.arange(n) / 30.0)
    assert v.shape == (n, mesh.num_vertices, 3)
    assert np.ptp(v.mean(1)[:, 0]) > 0.25  # the character travels with the recording
    mot = fx.io.read_bvh(tmp_path / "s_character.bvh")  # and its own skeleton as BVH
    assert sorted(mot.names) == sorted(mesh.joint_names) and mot.num_frames == n


def _mixamo_mood_setup():
    """The toy mood walk of test_motion_app with Mixamo joint names (8 roles resolve)."""
    import jax
    from helpers import TOY_OFFSETS, TOY_PARENTS
    from helpers import toy_clips as _clips

    from fxspace import motion as M

    names = ("Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "Spine", "Spine1", "LeftArm", "LeftHand")
    rng = np.random.default_rng(1)
    qL, rL = _clips(rng, 4, 20, 0.4)
    qU, rU = _clips(rng, 2, 16, 0.6)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.7)])
    sp = M.build_spaces(
        M.stack_examples(list(qL), list(rL), wl), M.stack_examples(list(qU), list(rU), wu),
        np.linspace(0, 15, 20), TOY_PARENTS, TOY_OFFSETS,
        mask=M.upper_body_mask(TOY_PARENTS, names, "Spine"), spine=4, lower_joint=3,
        lower_dims=(0, 2), lower_time=19.0, upper_joint=-1, upper_time=8.0,
        key=jax.random.PRNGKey(0), n_samples=60, knn_k=4, k_replace=5,
    )  # fmt: skip
    skel = fx.motion.Motion(
        names=names, parents=TOY_PARENTS, offsets=TOY_OFFSETS, root_translation=np.zeros((1, 3)),
        rotations=np.tile([1.0, 0, 0, 0], (1, len(names), 1)), rate=30.0,
        channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation",
                   "Xrotation"),) + (("Zrotation", "Yrotation", "Xrotation"),) * 7,
    )  # fmt: skip
    return M.Setup("mood_walk", sp, skel, 1.0, (3, 3), [], [], {})


@pytest.mark.slow
def test_browser_walker_wears_cesium_man_and_exports_it(data_dir, chromium, tmp_path):
    from fxspace.studio import serve_motion
    from fxspace.studio._server import ServeOptions

    opts = ServeOptions(port=0, block=False, environment_map=False)
    server, ctl = serve_motion(
        _mixamo_mood_setup(), playing=True, options=opts, export_path=tmp_path / "rec.bvh"
    )
    body = server.fxspace_view.body
    assert body.skin is not None and body.skin.visible and not body.limbs.visible
    with chromium.page(server, viewport={"width": 900, "height": 700}) as page:
        page.get_by_text("mood_walk", exact=False).first.wait_for(timeout=60_000)
        page.get_by_text("Capsule body").first.wait_for(timeout=60_000)
        for _ in range(200):  # the walker starts once the page has drawn the scene
            if ctl.frame > 3:
                break
            page.wait_for_timeout(100)
        v0 = np.asarray(body.skin.vertices).copy()
        shot0 = page.screenshot()
        f0 = ctl.frame
        for _ in range(200):
            if ctl.frame > f0 + 10:
                break
            page.wait_for_timeout(100)
        v1 = np.asarray(body.skin.vertices)
        assert np.abs(v1 - v0).max() > 0.01  # the skinned character moves
        size = np.ptp(v1, axis=0)  # a standing human: ~1.5 m tall, narrower than tall
        assert 1.2 < size[1] < 1.8 and size[0] < 0.8 * size[1] and size[2] < 0.8 * size[1]
        assert page.screenshot() != shot0  # and the page shows it moving
        page.get_by_role("button", name="Record").click()
        page.get_by_text("recording", exact=False).first.wait_for(timeout=60_000)
        page.wait_for_timeout(1500)
        page.get_by_role("button", name="Stop and write BVH").click()
        page.get_by_text("rec.glb", exact=False).first.wait_for(timeout=120_000)
    back = fx.io.read_gltf(tmp_path / "rec.glb")
    assert back.num_vertices == body.character.mesh.num_vertices and back.animation_names
