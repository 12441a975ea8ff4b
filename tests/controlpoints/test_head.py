"""The studio's head: a closed, smooth template head fitted to the markers and driven by
them only; the lips part when the jaw markers open."""

import numpy as np
import pytest

import fxspace as fx
from fxspace.controlpoints import head_model, head_vertices
from fxspace.controlpoints._head import _rbf


@pytest.fixture(scope="module")
def face():
    f = fx.synthetic.synthetic_face(seed=2)
    return np.asarray(f.sequence.positions, np.float64), list(f.sequence.names)


def _edges(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    return np.unique(e, axis=0, return_counts=True)


def test_rest_pose_and_rigid_motion(face):
    pos, names = face
    hm = head_model(pos[0], names, resolution=32)
    np.testing.assert_allclose(head_vertices(hm, pos[0]), hm.rest)
    # the transfer reproduces affine motion exactly (RBF with an affine part)
    R = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    moved = pos[0] @ R.T + [5.0, -3.0, 2.0]
    np.testing.assert_allclose(head_vertices(hm, moved), hm.rest @ R.T + [5.0, -3.0, 2.0],
                               atol=1e-6 * np.ptp(pos[0]))  # fmt: skip
    assert np.isfinite(hm.transfer).all() and hm.colors.shape == (len(hm.rest), 3)


def test_skin_is_closed_once_the_slit_is_shut(face):
    """At rest the mouth slit's two edges coincide; merging coincident points (the slit's
    copies, the poles) leaves a closed skin: every edge shared by two triangles."""
    pos, names = face
    hm = head_model(pos[0], names, resolution=32)
    skin = hm.faces[hm.part <= 2]
    key = np.round(hm.rest / (1e-7 * np.ptp(hm.rest)))
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    merged = first[inv.ravel()][skin]
    merged = merged[(merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2])
                    & (merged[:, 0] != merged[:, 2])]  # fmt: skip
    _, counts = _edges(merged)
    assert np.all(counts == 2)
    assert {"eyes", "irises", "mouth", "lips"} <= set(hm.parts)
    assert np.bincount(hm.part, minlength=6)[[1, 3, 4, 5]].min() > 0


def test_lips_part_when_the_jaw_opens(face):
    pos, names = face
    hm = head_model(pos[0], names, resolution=32)
    lo = [i for i, n in enumerate(names) if n.startswith(("lip_lower", "chin", "jaw"))]
    opened = pos[0].copy()
    opened[lo] -= hm.axes[1] * 12.0  # jaw down 12 mm
    V = head_vertices(hm, opened)
    edges, counts = _edges(hm.faces[hm.part <= 2])
    slit = edges[counts == 1]
    slit = slit[np.linalg.norm(hm.rest[slit[:, 0]] - hm.rest[slit[:, 1]], axis=1) > 1e-6]
    up = slit[hm.lower[slit].max(1) == 0].ravel()
    dn = slit[hm.lower[slit].min(1) == 1].ravel()
    gap = (V[up] @ hm.axes[1]).mean() - (V[dn] @ hm.axes[1]).mean()
    assert gap > 6.0  # the lower lip followed the jaw (12 mm down), the upper did not
    assert abs(((V[up] - hm.rest[up]) @ hm.axes[1]).mean()) < 2.0
    # at rest the lips touch (the slit is closed)
    assert abs((hm.rest[up] @ hm.axes[1]).mean() - (hm.rest[dn] @ hm.axes[1]).mean()) < 1e-6


def test_numpy_rbf_matches_the_library(face):
    pos, _ = face
    t = np.random.default_rng(1).normal(size=(50, 3)) * 30 + pos[0].mean(0)
    ref = np.asarray(fx.rbf_transfer_matrix(t, pos[0]))
    np.testing.assert_allclose(_rbf(t, pos[0]), ref, atol=1e-4)


def test_bad_inputs(face):
    pos, names = face
    with pytest.raises(fx.FxspaceError, match="rest_markers"):
        head_model(np.zeros((3, 3)))
    with pytest.raises(fx.FxspaceError, match="names"):
        head_model(pos[0], names[:3])
    with pytest.raises(fx.FxspaceError, match="resolution"):
        head_model(pos[0], names, resolution=4)
    hm = head_model(pos[0], None, resolution=24)  # no names: proportions
    with pytest.raises(fx.FxspaceError, match="markers"):
        head_vertices(hm, pos[0][:5])
