"""Control-point model: linear interpolation, eq. (1), exact rigid reconstruction, editing,
gradient fitting, jit/vmap/grad, real data."""

import jax
import jax.numpy as jnp
import matplotlib.figure
import numpy as np
import pytest
from helpers import check_grad

import fxspace as fx


def test_linear_interpolation_and_error_by_hand():
    first = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    last = np.array([[3.0, 0.0, 0.0], [1.0, 4.0, 1.0]])
    L = np.asarray(fx.linear_interpolation(first, last, 4))
    np.testing.assert_allclose(L[:, 0, 0], [0, 1, 2, 3])
    np.testing.assert_allclose(L[:, 1, 1], [1, 2, 3, 4])
    X = L.copy()
    X[1, 0] += [0.0, 2.0, 0.0]  # one vertex, one frame off by 2
    X[2, 1] += [1.0, 0.0, 1.0]  # another off by (1, 0, 1)
    assert float(fx.reconstruction_error(X, L)) == pytest.approx(4.0 + 2.0)


def _rigid_clusters(rng, T=12, per=15, k=3):
    """Each cluster translates rigidly along its own non-linear path."""
    P = rng.standard_normal((k * per, 3))
    labels = np.repeat(np.arange(k), per)
    paths = np.cumsum(rng.standard_normal((k, T, 3)), axis=1)
    X = P[None] + paths[labels].transpose(1, 0, 2)
    return X, labels


def test_exact_when_controls_are_cluster_means_on_rigid_motion(rng):
    X, labels = _rigid_clusters(rng)
    model = fx.control_point_model(X, labels, 3)
    np.testing.assert_allclose(np.asarray(fx.reconstruct(model)), X, atol=1e-12)
    lin = fx.linear_interpolation(X[0], X[-1], X.shape[0])
    assert float(fx.reconstruction_error(X, lin)) > 1.0
    # kernel k-means finds those clusters itself
    fitted, km = fx.fit_control_points(X, 3, key=jax.random.PRNGKey(0), n_init=5)
    assert float(fx.reconstruction_error(X, fx.reconstruct(fitted))) < 1e-20
    assert fx.compression_ratio(fitted) > 1.0
    T, N = X.shape[:2]
    assert fx.storage_size(fitted) == 2 * N * 3 + 3 * (T - 2) * 3 + N


def test_edit_moves_only_the_intended_region(rng):
    X, labels = _rigid_clusters(rng)
    model = fx.control_point_model(X, labels, 3)
    edited = fx.edit_control_point(model, 1, [0.0, 5.0, 0.0], center=5.0, width=4.0)
    d = np.asarray(fx.reconstruct(edited) - fx.reconstruct(model))
    moved = np.abs(d).max(axis=(0, 2)) > 0
    np.testing.assert_array_equal(moved, labels == 1)
    np.testing.assert_allclose(
        d[:, labels == 1, 1],
        np.asarray(fx.temporal_window(X.shape[0], 5.0, 4.0))[:, None] * 5.0 * np.ones((1, 15)),
        atol=1e-12,
    )
    assert np.all(d[0] == 0) and np.all(d[-1] == 0)  # key frames stay
    # blended weights: the edit spreads smoothly into the border, not beyond
    W = fx.blend_weights(X[0], labels, 3, radius=0.3)
    np.testing.assert_allclose(np.asarray(W.sum(1)), 1.0, atol=1e-12)
    soft = model._replace(weights=W)
    d2 = np.asarray(
        fx.reconstruct(fx.edit_control_point(soft, 1, [0.0, 5.0, 0.0])) - fx.reconstruct(soft)
    )
    np.testing.assert_array_equal(np.abs(d2).max(axis=(0, 2)) > 0, np.asarray(W[:, 1]) > 0)
    with pytest.raises(fx.FxspaceError, match="index"):
        fx.edit_control_point(model, 7, [0.0, 1.0, 0.0])


def test_gradient_of_eq1_vs_finite_differences(rng):
    X, labels = _rigid_clusters(rng, T=6, per=4)
    X = X + 0.1 * rng.standard_normal(X.shape)
    model = fx.control_point_model(X, labels, 3)
    f = lambda C: fx.reconstruction_error(X, fx.reconstruct(model._replace(controls=C)))
    check_grad(f, model.controls + 0.05, rng)
    g = lambda W: fx.reconstruction_error(X, fx.reconstruct(model._replace(weights=W)))
    check_grad(g, model.weights + 0.1, rng)


def test_jit_and_vmap(rng):
    X, labels = _rigid_clusters(rng)
    model = fx.control_point_model(X, labels, 3)
    np.testing.assert_allclose(
        np.asarray(jax.jit(fx.reconstruct)(model)), np.asarray(fx.reconstruct(model)), atol=1e-12
    )
    offs = jnp.array([[0.0, 1.0, 0.0], [2.0, 0.0, 0.0]])
    vm = jax.vmap(lambda o: fx.reconstruct(fx.edit_control_point(model, 0, o)))(offs)
    loop = np.stack([np.asarray(fx.reconstruct(fx.edit_control_point(model, 0, o))) for o in offs])
    np.testing.assert_allclose(np.asarray(vm), loop, atol=1e-12)


def test_gradient_refinement_lowers_error(rng):
    X, labels = _rigid_clusters(rng, T=10, per=10)
    X = X + 0.2 * rng.standard_normal(X.shape)
    W = fx.blend_weights(X[0], labels, 3, radius=0.5)
    model = fx.control_point_model(X, labels, 3, W)
    before = float(fx.reconstruction_error(X, fx.reconstruct(model)))
    res = fx.refine_control_points(X, model, steps=150, learning_rate=0.05, smoothness=0.0)
    assert float(res.error) < before
    assert res.losses.shape == (150,) and float(res.losses[-1]) < float(res.losses[0])
    np.testing.assert_allclose(np.asarray(res.model.weights.sum(1)), 1.0, atol=1e-9)


def test_plots(rng):
    X, labels = _rigid_clusters(rng)
    f1 = fx.plot.plot_control_points(X[0], labels)
    f2 = fx.plot.plot_reconstruction_frames([X[3], X[4]], ["a", "b"], reference=X[3])
    assert isinstance(f1, matplotlib.figure.Figure) and isinstance(f2, matplotlib.figure.Figure)


def test_real_face_segment_beats_linear(data_dir):
    """A real AnimFace segment on a small dense surface: ours well below linear."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    P = np.asarray(seq.positions, dtype=float)
    surf = fx.face_surface(P[0], 600)
    X = fx.rbf_deform(surf.vertices, P[0], P[300:352])
    lin = float(fx.reconstruction_error(X, fx.linear_interpolation(X[0], X[-1], X.shape[0])))
    model, km = fx.fit_control_points(X, 20, gamma=0.5, key=jax.random.PRNGKey(0), n_init=4)
    ours = float(fx.reconstruction_error(X, fx.reconstruct(model)))
    assert ours < 0.11 * lin


@pytest.mark.slow
def test_reconstruction_pipeline_smoke(data_dir, tmp_path):
    """The experiment end to end on a small surface (run with -m slow)."""
    from fxspace.pipelines import run_dict

    raw = {
        "experiment": "reconstruction",
        "seed": 0,
        "n_vertices": 400,
        "n_segments": 8,  # the paper's count, overriding the count chosen from the data
        "clusters": [20],
        "gammas": [0.5],
        "n_init": 2,
        "fit_steps": 20,
        "timing_repeats": 1,
        "gltf_mesh": "",
    }
    ict = (data_dir / "face" / "ict").is_dir()
    if ict:  # the dense sequence from the solved head (issue 30.6); the RBF surface beside
        raw["dense_source"] = "head"
    (run_dir,) = run_dict(raw, tmp_path, force=True)
    import json

    m = json.loads((run_dir / "metrics.json").read_text())
    assert m["ratio"] < 0.11 and m["segmentation"]["n_segments"] == 8
    assert m["error_ratio_scene"] < 0.11 and len(m["error_ratio_segments"]) == 8
    assert max(m["error_ratio_segments"]) < 0.11 and m["scene_pipeline_time_s"] > 0
    assert m["n_segments_chosen"] == 8 and "config" in m["n_segments_why"]
    lo, hi = m["paper_segment"]["frames"]
    assert m["error_ratio_paper_segment"] == m["error_ratio_segments"][m["paper_segment"]["index"]]
    assert (run_dir / "character.glb").is_file()
    for name in (
        "reconstruction.png",
        "segmentation.png",
        "scene_errors.png",
        "edited_sequence.npz",
        "edited_markers.trc",
        "scene.npz",
        "edits.json",
    ):
        assert (run_dir / name).is_file()
    seq = fx.io.read_markers(run_dir / "edited_markers.trc")
    assert seq.positions.shape == (150, 41, 3)
    # the character and the real head carry the animator's edit (issue 30.5)
    assert m["character"]["carries_edits"] and m["character"]["edit_moved_vertices"] > 0
    if ict:
        by = m["error_ratio_by_dense_source"]
        assert m["dense_source"] == "head" and set(by) == {"head", "rbf"}
        assert by["head"]["n_vertices"] == 9409 and by["rbf"]["n_vertices"] <= 400
        assert m["n_segments_chosen"] == 8 and m["data"]["n_vertices"] == 9409
        for k in ("head", "rbf"):  # the paper's ratio (ours / linear) for each, named
            assert 0 < by[k]["error_ratio_scene"] < 0.11
            assert m[f"error_ratio_scene_{k}"] == by[k]["error_ratio_scene"]
        assert by["head"]["error_ratio_scene"] == m["error_ratio_scene"]
        h = m["head"]
        assert h["n_shapes"] == 53 and h["residual_mean"] < h["residual_rigid_only_mean"]
        assert h["edit_weight_change_max"] > 0.01 and h["converged_fraction"] > 0.5
        bs = fx.io.read_gltf_blendshapes(run_dir / "head.glb")
        W, names, _ = fx.face.read_weights_csv(run_dir / "head_weights.csv")
        assert bs.names == names and "jawOpen" in names
        np.testing.assert_allclose(bs.weights, W, atol=1e-5)


def test_kernel_kmeans_to_the_end_is_a_fixed_point(rng):
    """Issue 31.3: with more vertices than ``max_points`` the default (``method="kernel"``)
    runs kernel k-means on every vertex to its fixed point: one more kernel k-means step
    from the final labels changes none. The hybrid (Euclidean steps after the subset) is
    a named option and, on a noisy scene, ends on a different partition."""
    from fxspace.controlpoints._model import _features, _pad_frames, frame_bucket

    T, k, per = 14, 4, 60
    t = np.linspace(0, 1, T)[:, None, None]
    base = rng.normal(size=(k * per, 3))
    paths = rng.normal(size=(k, 3)) * 2.0
    lab = np.repeat(np.arange(k), per)
    X = base[None] + np.sin(np.pi * t) * paths[lab][None] + rng.normal(0, 0.6, (T, k * per, 3))
    key = jax.random.key(0)
    m, km = fx.fit_control_points(X, k, key=key, n_init=4, max_points=60)
    mh, _ = fx.fit_control_points(X, k, key=key, n_init=4, max_points=60, method="hybrid")
    assert km.labels.shape == (k * per,) and km.result == fx.RESULTS.successful
    F = _features(_pad_frames(np.asarray(X), frame_bucket(T)), jnp.asarray(T))
    gamma = float(fx.median_gamma(F))
    again = fx.kernel_kmeans(F, k, gamma, key=key, init=m.labels[None], max_steps=1)
    np.testing.assert_array_equal(np.asarray(again.labels), np.asarray(m.labels))
    np.testing.assert_array_equal(np.asarray(km.labels), np.asarray(m.labels))
    assert mh.labels.shape == m.labels.shape
    with pytest.raises(fx.errors.FxspaceError, match="method"):
        fx.fit_control_points(X, k, key=key, method="lloyd")


def test_fit_scene_passes_its_segment_criterion_on(rng):
    """``fit_scene(n_segments="auto")`` chooses the count by its ``segment_criterion``
    (it used to fall back to segment_motion's BIC whatever the caller wanted)."""
    T, N = 60, 30
    t = np.arange(T)[:, None, None]
    X = np.where(t < 20, 0.0, np.where(t < 40, 1.0, -0.5)) * np.ones((1, N, 3))
    X = X + rng.normal(0, 0.02, (T, N, 3))
    for crit in ("elbow", "bic"):
        fit = fx.fit_scene(X, 3, n_segments="auto", segment_criterion=crit, n_init=2,
                           key=jax.random.key(0))  # fmt: skip
        ref = fx.segment_motion(jnp.asarray(X), "auto", criterion=crit)
        np.testing.assert_array_equal(fit.segmentation.boundaries, ref.boundaries)


def test_reconstruction_dense_source_is_checked():
    from fxspace.config import ConfigError
    from fxspace.pipelines.reconstruction import Config

    Config(dense_source="head").validate()
    with pytest.raises(ConfigError, match="dense_source must be 'rbf'"):
        Config(dense_source="mesh").validate()
    with pytest.raises(ConfigError, match="needs a rig"):
        Config(dense_source="head", file="synthetic").validate()
    with pytest.raises(ConfigError, match="needs a rig"):
        Config(dense_source="head", head="").validate()
