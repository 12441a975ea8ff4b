"""Key-framed control-point edits: interpolation against scipy's cubic Hermite, the region
follows through the weights, continuity, last-key-wins history, JSON round trip, jit."""

import json

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


# --- keys anchored on the face (issue 21) ----------------------------------------------

from fxspace.controlpoints import FaceKey  # noqa: E402


def test_face_key_offsets_hold_across_a_boundary_and_match_hermite(rng):
    """Two keys with one offset hold it across the boundary (frame 10); outside the keys it
    eases to zero at the surrounding boundaries (scipy's zero-slope Hermite)."""
    X, scene = _scene(rng)
    o = np.array([1.0, -2.0, 0.5])
    keys = [FaceKey(8, 0, tuple(o)), FaceKey(13, 0, tuple(o))]
    path = fx.controlpoints.anchor_offsets(keys, scene.boundaries)[0]
    ref = CubicHermiteSpline([0, 8, 13, 20.0], np.array([0 * o, o, o, 0 * o]), np.zeros((4, 3)))
    np.testing.assert_allclose(path, ref(np.arange(21)), atol=1e-12)
    np.testing.assert_allclose(path[8:14], np.tile(o, (6, 1)), atol=1e-12)  # held
    base = np.asarray(fx.reconstruct_scene(scene))
    ed = fx.controlpoints.edited_vertices(scene, keys)
    np.testing.assert_allclose(ed[10, 0] - base[10, 0], o, atol=1e-9)  # the boundary frame too
    # the anchor's region: vertices of its cluster in each segment (one-hot weights here)
    k0, k1 = (int(np.argmax(np.asarray(m.weights)[0])) for m in scene.segments)
    W0 = np.asarray(scene.segments[0].weights[:, k0])
    np.testing.assert_allclose(ed[8] - base[8], W0[:, None] * o, atol=1e-9)
    # a key at a boundary frame itself and at the scene's ends is valid
    ed2 = fx.controlpoints.edited_vertices(
        scene, [FaceKey(10, 5, (0, 0, 1.0)), FaceKey(0, 5, (1.0, 0, 0))]
    )
    np.testing.assert_allclose(ed2[10, 5] - base[10, 5], [0, 0, 1.0], atol=1e-9)
    np.testing.assert_allclose(ed2[0, 5] - base[0, 5], [1.0, 0, 0], atol=1e-9)


def test_segment_blend_is_a_partition_and_cross_fades(rng):
    A = fx.controlpoints.segment_blend([0, 10, 20], blend=4)
    np.testing.assert_allclose(A.sum(1), 1.0)
    np.testing.assert_allclose(A[10], [0.5, 0.5])
    np.testing.assert_array_equal(A[:7, 0], 1.0)
    np.testing.assert_array_equal(A[14:, 1], 1.0)
    assert np.all(np.diff(A[:, 1]) >= 0)  # monotone hand-over


def test_old_keys_convert_and_reproduce_the_old_edit(rng, tmp_path):
    """A version-1 edits.json (per-segment keys) loads and converts to keys on the face that
    give the old edit wherever the cross-fade does not reach (and at the anchor everywhere)."""
    X, scene = _scene(rng)
    k = int(scene.segments[1].labels[0])
    old = [EditKey(1, k, 15, (1.0, 2.0, 0.0))]
    p = fx.save_edits(tmp_path / "edits.json", old, boundaries=[0, 10, 20])
    back, meta = fx.load_edits(p)
    assert back == old
    new = fx.controlpoints.convert_keys(scene, back)
    v = new[0].vertex
    assert isinstance(new[0], FaceKey) and int(scene.segments[1].labels[v]) == k
    was = np.asarray(fx.reconstruct_scene(fx.apply_edits(scene, old)))
    now = fx.controlpoints.edited_vertices(scene, new)
    np.testing.assert_allclose(now[14:17], was[14:17], atol=1e-9)
    np.testing.assert_allclose(now[:, v], was[:, v], atol=1e-9)
    # round trip of face keys (version 2)
    p2 = fx.save_edits(tmp_path / "e2.json", new)
    assert fx.load_edits(p2)[0] == new and json.loads(p2.read_text())["version"] == 2


def test_bad_edits_are_refused(rng, tmp_path):
    X, scene = _scene(rng)
    with pytest.raises(fx.FxspaceError, match="finite"):
        fx.controlpoints.edited_vertices(scene, [FaceKey(3, 0, (np.nan, 0.0, 0.0))])
    with pytest.raises(fx.FxspaceError, match="finite"):
        fx.save_edits(tmp_path / "e.json", [FaceKey(3, 0, (0.0, np.inf, 0.0))])
    with pytest.raises(fx.FxspaceError, match="frame"):
        fx.controlpoints.edited_vertices(scene, [FaceKey(21, 0, (1.0, 0.0, 0.0))])
    with pytest.raises(fx.FxspaceError, match="vertex"):
        fx.controlpoints.edited_vertices(scene, [FaceKey(3, 36, (1.0, 0.0, 0.0))])
    with pytest.raises(fx.FxspaceError, match="finite"):
        fx.controlpoints.edit_control_keys(scene.segments[0], 0, [3], [[np.nan, 0, 0]])
    for text in ("{not json", '{"keys": 3}', '{"keys": [{"frame": 1}]}', "[1, 2]"):
        (tmp_path / "bad.json").write_text(text)
        with pytest.raises(fx.errors.CorruptFileError, match="bad.json"):
            fx.load_edits(tmp_path / "bad.json")
