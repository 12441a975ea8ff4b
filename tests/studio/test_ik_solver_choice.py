"""The IK studio offers the paper's gradient path (issue 47.3): the solver dropdown's
choices reach `solve_ik` — BFGS on eq. (13), on eq. (9), or Levenberg–Marquardt."""

import numpy as np
import pytest

import fxspace as fx
from fxspace.studio import IKController
from fxspace.studio._ik import status_text
from fxspace.studio._ik_controller import IK_SOLVERS


@pytest.fixture(scope="module")
def mesh(data_dir):
    return fx.io.read_gltf(data_dir / "mesh" / "RiggedSimple.glb")


def test_each_solver_reaches_the_target(mesh):
    assert list(IK_SOLVERS) == ["lm", "bfgs_factored", "bfgs_naive"]
    size = float(np.ptp(mesh.vertices, axis=0).max())
    poses = {}
    for name in IK_SOLVERS:
        ctl = IKController(mesh)
        ctl.set_solver(name)
        vis = np.flatnonzero(ctl.visible((0.0, 0.0, -1.0)))
        for t in np.random.default_rng(0).choice(vis, 3, replace=False):
            ctl.add_marker(int(t), view_dir=(0.0, 0.0, -1.0))
        p0 = ctl.marker_points()[0]
        goal = p0 + np.array([0.1 * size, 0.0, 0.0])
        ctl.move_target(0, goal)
        assert ctl.message.startswith(f"{name}: solved")
        assert f"Solver: {IK_SOLVERS[name]}" in status_text(ctl.status())
        assert np.linalg.norm(ctl.marker_points()[0] - goal) < 0.5 * np.linalg.norm(p0 - goal)
        poses[name] = ctl.marker_points()
    # BFGS on eq. (13) and on eq. (9) follow the same gradient: the markers land alike
    np.testing.assert_allclose(poses["bfgs_factored"], poses["bfgs_naive"], atol=1e-2 * size)
    with pytest.raises(fx.FxspaceError, match="solver must be one of"):
        IKController(mesh).set_solver("newton")
