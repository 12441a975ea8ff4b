"""The paper's range of models: a subdivided skinned mesh (weights interpolated) and a
procedurally built long chain."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_toys import branching_mesh, random_pose

import fxspace as fx
from fxspace.errors import FxspaceError


def _area(v, f):
    return np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()


def test_subdivision_keeps_the_surface_and_interpolates_the_weights(rng):
    m = branching_mesh(0)
    target = fx.mesh.subdivide_mesh(m, levels=1).num_vertices + 5  # one round + 5 centroids
    s = fx.mesh.subdivide_mesh(m, num_vertices=target)
    assert s.num_vertices == target and s.num_joints == m.num_joints
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    # planar splits: the same surface, the original vertices and weights first
    np.testing.assert_allclose(_area(v, f), _area(np.asarray(m.vertices), np.asarray(m.faces)))
    np.testing.assert_array_equal(v[: m.num_vertices], m.vertices)
    np.testing.assert_allclose(s.skin_weights.sum(1), 1.0)
    pose = random_pose(rng, m.num_joints)
    a, b = np.asarray(fx.pose_vertices(m, pose)), np.asarray(fx.pose_vertices(s, pose))
    np.testing.assert_allclose(b[: m.num_vertices], a, atol=1e-10)
    # a midpoint's weights are the mean of its edge's: rigid parts pose it at the midpoint
    e0, e1 = np.asarray(m.faces)[0, :2]
    mid = np.flatnonzero(np.all(np.isclose(v, 0.5 * (v[e0] + v[e1])), axis=1))
    assert mid.size == 1
    dense = np.zeros((s.num_vertices, s.num_joints))
    np.add.at(dense, (np.arange(s.num_vertices)[:, None], s.skin_joints), s.skin_weights)
    np.testing.assert_allclose(dense[mid[0]], 0.5 * (dense[e0] + dense[e1]), atol=1e-12)
    one = fx.mesh.subdivide_mesh(m, levels=1)
    assert one.faces.shape[0] == 4 * m.faces.shape[0]
    with pytest.raises(FxspaceError, match="below the mesh"):
        fx.mesh.subdivide_mesh(m, num_vertices=3)
    with pytest.raises(FxspaceError, match="num_vertices must be an integer"):
        fx.mesh.subdivide_mesh(m, num_vertices=2.5)


@pytest.mark.slow
def test_cesium_man_at_the_papers_size(data_dir):
    path = data_dir / "mesh" / "CesiumMan.glb"
    if not path.exists():
        pytest.skip(f"{path} not found (set FXSPACE_DATA to the data root)")
    m = fx.io.read_gltf(path)
    s = fx.mesh.subdivide_mesh(m, num_vertices=13800)
    assert s.num_vertices == 13800
    t = np.linspace(*m.animation_range(0), 3)
    a = fx.mesh.animation_vertices(m, 0, t)
    b = fx.mesh.animation_vertices(s, 0, t)
    np.testing.assert_allclose(b[:, : m.num_vertices], a, atol=1e-5)


def test_chain_mesh_is_a_deep_skinned_tube():
    c = fx.mesh.chain_mesh(41)
    assert c.num_joints == 41 and np.all(c.parents[1:] == np.arange(40))
    assert fx.mesh.ancestor_table(c.parents).shape[1] == 41  # depth 41
    np.testing.assert_allclose(fx.mesh.rest_vertices(c), c.vertices, atol=1e-9)
    v = fx.mesh.animation_vertices(c, "wave", [0.0, 0.5])
    assert np.all(np.isfinite(v)) and np.abs(v[1] - c.vertices).max() > 0.01
    # outward faces: the normals point away from the tube's axis
    n = np.asarray(fx.triangle_normals(c.vertices, c.faces))
    centre = np.asarray(c.vertices)[np.asarray(c.faces)].mean(1)
    assert np.all(np.einsum("fc,fc->f", n[:, 1:], centre[:, 1:]) > 0)
    ms = fx.place_markers(c.vertices, c.faces, 40, view_dir=(0.0, -1.0, 0.0), seed=0)
    model = fx.ik_model(c, ms)
    assert model.hops.shape[0] == 4  # ⌈log₃ 41⌉ pointer-jumping steps
