"""The IK app loads a BVH take and shows it retargeted onto its mesh (issue 48.4):
`IKController.load_take` (`fxspace.mesh.retarget`), played frame by frame, the source's
joints, the character's and the feet in contact drawn, the played frames exported."""

from __future__ import annotations

import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import FxspaceError
from fxspace.studio import IKController

BANDAI = ("body", "bandai", "dataset-1_walk-left_normal_001.bvh.gz")


def test_missing_take_is_refused_naming_it(tmp_path):
    ctl = IKController(fx.mesh.chain_mesh(num_joints=4, frames=2))
    with pytest.raises(FxspaceError, match="nowhere.bvh"):
        ctl.load_take(tmp_path / "nowhere.bvh")
    assert ctl.take is None and not ctl.toggle_play()  # nothing to play
    assert "load a BVH take" in ctl.message


@pytest.mark.slow
def test_bandai_walk_retargeted_played_drawn_and_exported(data_dir, tmp_path):
    from fxspace.studio import serve_ik

    path = data_dir.joinpath(*BANDAI)
    server, ctl = serve_ik(data_dir / "mesh" / "CesiumMan.glb", port=0, block=False,
                           export_path=tmp_path / "take.bvh", take=path)  # fmt: skip
    try:
        view = server.fxspace_view
        assert ctl.take is not None and not view.play_btn.disabled
        assert ctl.status()["take"] == path.name and "retargeted" in ctl.message
        n = len(ctl.take.joint_error)
        assert n > 30 and float(np.nanmedian(ctl.take.joint_error)) < 0.1  # heights
        v0 = ctl.vertices.copy()
        assert ctl.toggle_play()
        for _ in range(n):  # one full pass, then wrapping to the first frame
            ctl.step()
            view._redraw(gizmos=False)  # draws the take's overlay without a browser
        assert ctl.take_frame == 0 and len(ctl.recorded) == n
        np.testing.assert_allclose(ctl.vertices, v0, atol=1e-5)  # back at frame 0
        ctl.step()
        assert np.abs(ctl.vertices - v0).max() > 1e-3  # the skinned mesh moves
        src, char, contact = ctl.take_overlay()
        assert src.shape == char.shape == (len(ctl.take.correspondences), 3)
        assert ctl.take.contacts.any(axis=1).mean() > 0.5  # a walk: a foot down mostly
        ctl.toggle_play()
        out = ctl.export_bvh(tmp_path / "take.bvh")
        mot = fx.io.read_bvh(out)
        assert sorted(mot.names) == sorted(ctl.mesh.joint_names) and mot.num_frames == n + 1
    finally:
        server.stop()
