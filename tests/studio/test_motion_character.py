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
