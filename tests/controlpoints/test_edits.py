"""Key-framed control-point edits: interpolation against scipy's cubic Hermite, the region
follows through the weights, continuity, last-key-wins history, JSON round trip, jit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

import fxspace as fx
from fxspace.controlpoints import EditKey


def test_keyed_offsets_match_zero_slope_hermite():
    T = 21
    frames = np.array([12, 4])
    off = np.array([[1.0, -2.0, 0.5], [3.0, 0.0, 1.0]])
    got = np.asarray(fx.controlpoints.keyed_offsets(T, frames, off))
    knots = np.array([0, 4, 12, 20.0])
    vals = np.array([[0, 0, 0], off[1], off[0], [0, 0, 0]])
    ref = CubicHermiteSpline(knots, vals, np.zeros_like(vals))(np.arange(T))
    np.testing.assert_allclose(got, ref, atol=1e-12)
    np.testing.assert_allclose(got[[0, -1]], 0.0)
    np.testing.assert_allclose(got[4], off[1])
    # jit: same values; no overshoot beyond the keys
    jitted = jax.jit(fx.controlpoints.keyed_offsets, static_argnums=0)(T, frames, off)
    np.testing.assert_allclose(np.asarray(jitted), got, atol=1e-12)
    assert got[:, 0].max() <= 3.0 + 1e-12 and got[:, 1].min() >= -2.0 - 1e-12


def _scene(rng):
    """Three rigid clusters of 12 vertices, two segments of 11 frames (the shapes of
    test_scene, so the compiled kernels are shared)."""
    P = rng.standard_normal((36, 3))
    labels = np.repeat(np.arange(3), 12)
    paths = np.cumsum(rng.standard_normal((3, 21, 3)), axis=1)
    X = P[None] + paths[labels].transpose(1, 0, 2)
    fit = fx.fit_scene(X, 3, boundaries=[0, 10, 20], key=jax.random.PRNGKey(0), n_init=5)
    return X, fit.model


def test_edits_move_only_the_region_and_keep_boundaries(rng):
    X, scene = _scene(rng)
    base = np.asarray(fx.reconstruct_scene(scene))
    k = int(scene.segments[1].labels[0])  # the control point of vertices 0 … 9
    keys = [EditKey(1, k, 13, (1.0, 2.0, 0.0)), EditKey(1, k, 17, (0.0, 0.0, -1.0))]
    ed = np.asarray(fx.reconstruct_scene(fx.apply_edits(scene, keys)))
    moved = np.abs(ed - base).max(axis=(0, 2)) > 1e-12
    W = np.asarray(scene.segments[1].weights[:, k])
    np.testing.assert_array_equal(moved, W > 0)
    np.testing.assert_allclose(ed[13] - base[13], W[:, None] * [1.0, 2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(ed[17] - base[17], W[:, None] * [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(ed[:11], base[:11], atol=1e-12)  # segment 0 + the boundary
    np.testing.assert_allclose(ed[20], base[20], atol=1e-12)
    # a later key at the same frame replaces the earlier; the history is the list
    keys2 = [*keys, EditKey(1, k, 13, (0.0, 0.0, 0.0))]
    ed2 = np.asarray(fx.reconstruct_scene(fx.apply_edits(scene, keys2)))
    np.testing.assert_allclose(ed2[13], base[13], atol=1e-12)
    with pytest.raises(fx.FxspaceError, match="in-between"):
        fx.apply_edits(scene, [EditKey(1, k, 10, (1.0, 0.0, 0.0))])
    with pytest.raises(fx.FxspaceError, match="control"):
        fx.apply_edits(scene, [EditKey(1, 7, 13, (1.0, 0.0, 0.0))])
    seg, C = fx.control_positions(fx.apply_edits(scene, keys), 13)
    _, C0 = fx.control_positions(scene, 13)
    assert seg == 1
    np.testing.assert_allclose(C[k] - C0[k], [1.0, 2.0, 0.0], atol=1e-12)


def test_save_load_round_trip(rng, tmp_path):
    X, scene = _scene(rng)
    keys = [EditKey(0, 2, 5, (0.25, -1.5, 3.0)), EditKey(1, 0, 18, (1e-3, 0.0, 7.0))]
    p = fx.save_edits(tmp_path / "edits.json", keys, boundaries=[0, 10, 20])
    back, meta = fx.load_edits(p)
    assert back == keys and meta["boundaries"] == [0, 10, 20]
    a = fx.reconstruct_scene(fx.apply_edits(scene, keys))
    b = fx.reconstruct_scene(fx.apply_edits(scene, back))
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_edit_control_keys_gradient_is_the_weights(rng):
    X, scene = _scene(rng)
    m = scene.segments[0]

    def f(o):
        e = fx.controlpoints.edit_control_keys(m, 1, [6], o[None, :])
        return jnp.sum(fx.reconstruct(e)[6])

    g = np.asarray(jax.grad(f)(jnp.zeros(3)))
    np.testing.assert_allclose(g, np.full(3, float(np.sum(m.weights[:, 1]))), rtol=1e-12)
