"""RBF marker → mesh transfer: interpolation, affine reproduction, scipy reference, real data."""

import numpy as np
import pytest

import fxspace as fx


def test_interpolates_sources_and_reproduces_affine(rng):
    S = rng.standard_normal((20, 3))
    A = np.asarray(fx.rbf_transfer_matrix(S, S))
    np.testing.assert_allclose(A, np.eye(20), atol=1e-9)
    X = rng.standard_normal((50, 3))
    A = np.asarray(fx.rbf_transfer_matrix(X, S))
    M, b = rng.standard_normal((3, 3)), rng.standard_normal(3)
    np.testing.assert_allclose(A @ (S @ M.T + b), X @ M.T + b, atol=1e-9)


def test_matches_scipy_rbf_interpolator(rng):
    scipy_interp = pytest.importorskip("scipy.interpolate")
    S = rng.standard_normal((25, 3))
    f = rng.standard_normal((25, 2))
    X = rng.standard_normal((40, 3))
    ref = scipy_interp.RBFInterpolator(S, f, kernel="linear", degree=1)(X)
    # scipy's "linear" kernel is -r; with the affine part the interpolant is the same
    np.testing.assert_allclose(np.asarray(fx.rbf_transfer_matrix(X, S)) @ f, ref, atol=1e-8)
    ref2 = scipy_interp.RBFInterpolator(S[:, :2], f, kernel="thin_plate_spline", degree=1)(X[:, :2])
    np.testing.assert_allclose(
        np.asarray(fx.rbf_transfer_matrix(X[:, :2], S[:, :2], "thin_plate")) @ f, ref2, atol=1e-8
    )


def test_rigid_motion_transfers_exactly(rng):
    m0 = rng.standard_normal((12, 3))
    V = rng.standard_normal((30, 3))
    th = 0.3
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    markers = np.stack([m0, m0 @ R.T + [1.0, 2.0, 3.0]])
    out = np.asarray(fx.rbf_deform(V, m0, markers))
    np.testing.assert_allclose(out[0], V, atol=1e-10)
    np.testing.assert_allclose(out[1], V @ R.T + [1.0, 2.0, 3.0], atol=1e-9)
    with pytest.raises(fx.FxspaceError, match="NaN"):
        fx.rbf_deform(V, m0, np.where(markers > 1.5, np.nan, markers))


def test_face_surface_on_real_markers(data_dir):
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    P = np.asarray(seq.positions[:5], dtype=float)
    surf = fx.face_surface(P[0], 2000)
    assert 1600 < surf.vertices.shape[0] < 2400
    assert surf.faces.shape[1] == 3 and surf.faces.max() < surf.vertices.shape[0]
    # the surface passes close to every marker (depth is interpolated through them)
    d = np.linalg.norm(surf.vertices[surf.marker_vertex] - P[0], axis=1)
    assert d.max() < 5.0  # mm: within a grid spacing
    X = np.asarray(fx.rbf_deform(surf.vertices, P[0], P))
    assert X.shape == (5, surf.vertices.shape[0], 3) and np.all(np.isfinite(X))


def test_coinciding_markers_are_refused_not_nan(rng):
    m0 = rng.standard_normal((8, 3))
    m0[5] = m0[2]
    V = rng.standard_normal((20, 3))
    with pytest.raises(fx.FxspaceError, match="same place"):
        fx.rbf_deform(V, m0, np.repeat(m0[None], 3, 0))
