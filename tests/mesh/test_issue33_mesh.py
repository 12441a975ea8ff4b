"""Issue 33 (mesh IK): a zero target normal is refused, never "successful"."""

from __future__ import annotations

import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import FxspaceError


def test_solve_ik_zero_target_normal_refused():
    from mesh_toys import both_views, branching_mesh

    m = branching_mesh(0, uniform_scale=1.7)
    ms = both_views(m, 20, 20)
    model = fx.ik_model(m, ms)
    nc = fx.mesh.normal_constraint(m, ms, weight=1.0)
    tn = np.array(fx.mesh.marker_normals(nc.corners, fx.rest_pose(m)))
    tn[0] = 0.0
    targets = fx.ik_markers(model, fx.rest_pose(m))
    cons = fx.mesh.ik_constraints(model, normal=nc)
    with pytest.raises(FxspaceError, match="target_normals"):
        fx.solve_ik(model, targets, constraints=cons, target_normals=tn)
