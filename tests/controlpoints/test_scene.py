"""Whole-scene control points: stitched segments, continuity at shared boundary frames,
per-segment and scene errors against numpy, storage, thinning, round trip of the arrays."""

import jax
import numpy as np
import pytest

import fxspace as fx


def _scene_data(rng, T=31, per=12, k=3, bounds=(0, 10, 20, 30)):
    """Clusters moving rigidly along their own paths, with velocity changes at ``bounds``."""
    P = rng.standard_normal((k * per, 3))
    labels = np.repeat(np.arange(k), per)
    paths = np.cumsum(rng.standard_normal((k, T, 3)), axis=1)
    return P[None] + paths[labels].transpose(1, 0, 2), labels, np.asarray(bounds)


def test_exact_on_rigid_clusters_and_continuous(rng):
    X, labels, b = _scene_data(rng)
    fit = fx.fit_scene(X, 3, boundaries=b, key=jax.random.PRNGKey(0), n_init=5)
    assert fit.segmentation is None and len(fit.model.segments) == 3
    Xh = np.asarray(fx.reconstruct_scene(fit.model))
    assert Xh.shape == X.shape
    np.testing.assert_allclose(Xh, X, atol=1e-9)  # each cluster is one control point
    np.testing.assert_array_equal(Xh[b], X[b])  # key frames stored exactly
    e = fx.scene_errors(X, fit.model)
    assert e.ratio_scene < 1e-12 and np.all(e.ratio < 1e-12)


def test_errors_and_baseline_against_numpy(rng):
    X, _, b = _scene_data(rng)
    X = X + 0.3 * rng.standard_normal(X.shape)
    fit = fx.fit_scene(X, 2, boundaries=b, key=jax.random.PRNGKey(1), n_init=3)
    L = np.asarray(fx.linear_scene(X, b))
    Xh = np.asarray(fx.reconstruct_scene(fit.model))
    lin, mod = [], []
    for a, c in zip(b[:-1], b[1:], strict=True):
        s = np.linspace(0, 1, c - a + 1)[:, None, None]
        ref = X[a] + s * (X[c] - X[a])
        np.testing.assert_allclose(L[a : c + 1], ref, atol=1e-12)
        lin.append(np.sum((X[a : c + 1] - ref) ** 2))
        mod.append(np.sum((X[a : c + 1] - Xh[a : c + 1]) ** 2))
    e = fx.scene_errors(X, fit.model)
    np.testing.assert_allclose(e.linear, lin)
    np.testing.assert_allclose(e.model, mod)
    # every frame once: the scene error is the whole-sequence eq. (1)
    assert e.model_scene == pytest.approx(np.sum((X - Xh) ** 2))
    assert e.linear_scene == pytest.approx(np.sum((X - L) ** 2))
    assert e.ratio_scene == pytest.approx(e.model_scene / e.linear_scene)
    assert 0 < e.ratio_scene < 1


def test_segmented_storage_thinning_and_arrays(rng):
    X, _, _ = _scene_data(rng, T=40, bounds=(0, 39))
    fit = fx.fit_scene(X, 3, n_segments=3, min_length=4, key=jax.random.PRNGKey(0), n_init=3)
    b = fit.model.boundaries
    assert fit.segmentation is not None and len(b) == 4 and b[0] == 0 and b[-1] == 39
    N = X.shape[1]
    per = sum(3 * (int(c - a) - 1) * 3 + N for a, c in zip(b[:-1], b[1:], strict=True))
    assert fx.scene_storage_size(fit.model) == 4 * N * 3 + per
    assert fx.scene_compression_ratio(fit.model) == pytest.approx(40 * N * 3 / (4 * N * 3 + per))
    back = fx.controlpoints.scene_from_arrays(fx.controlpoints.scene_to_arrays(fit.model))
    np.testing.assert_array_equal(
        np.asarray(fx.reconstruct_scene(back)), np.asarray(fx.reconstruct_scene(fit.model))
    )
    # the paper's thinning: 300 → 150, the even-numbered (1-based) frames dropped
    Y = np.arange(300)[:, None, None] * np.ones((1, 2, 3))
    Z = np.asarray(fx.thin_frames(Y, 2))
    assert Z.shape[0] == 150 and Z[0, 0, 0] == 0 and Z[1, 0, 0] == 2
    assert fx.segment_of_frame(b, 0) == (0, 0)
    assert fx.segment_of_frame(b, int(b[1])) == (1, 0)
    assert fx.segment_of_frame(b, 39) == (2, int(39 - b[2]))
    with pytest.raises(fx.FxspaceError, match="boundaries"):
        fx.fit_scene(X, 3, boundaries=[0, 1, 39])
    with pytest.raises(fx.FxspaceError, match="frame"):
        fx.segment_of_frame(b, 40)


def test_refined_scene_beats_plain(rng):
    X, _, b = _scene_data(rng)
    X = X + 0.2 * rng.standard_normal(X.shape)
    plain = fx.fit_scene(X, 2, boundaries=b, key=jax.random.PRNGKey(0), n_init=3)
    fitted = fx.fit_scene(X, 2, boundaries=b, key=jax.random.PRNGKey(0), n_init=3, fit_steps=60)
    e_fit, e_plain = fx.scene_errors(X, fitted.model), fx.scene_errors(X, plain.model)
    assert e_fit.model_scene < e_plain.model_scene
    assert len(fitted.num_steps) == 3 and all(s == 60 for s in fitted.num_steps)


@pytest.mark.slow
def test_whole_real_scene_beats_linear(data_dir):
    """AnimFace, 120 captured frames thinned to 60, a small surface: every segment and the
    scene well below linear interpolation (the paper's ratio is 0.11)."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    M = np.asarray(fx.thin_frames(np.asarray(seq.positions, float)[300:420], 2))
    surf = fx.face_surface(M[0], 500)
    X = fx.rbf_deform(surf.vertices, M[0], M)
    fit = fx.fit_scene(X, 20, n_segments=4, gamma=0.5, key=jax.random.PRNGKey(0), n_init=4)
    e = fx.scene_errors(X, fit.model)
    assert e.ratio_scene < 0.11 and np.all(e.ratio < 0.11)
    Xh = np.asarray(fx.reconstruct_scene(fit.model))
    np.testing.assert_allclose(Xh[fit.model.boundaries], np.asarray(X)[fit.model.boundaries])
