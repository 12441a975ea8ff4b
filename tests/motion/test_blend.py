"""Blend weights (sampling, k-NN of Kovar & Gleicher 2004) and quaternion blending."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fxspace.motion import (
    ExampleSet,
    blend_pose,
    blend_quaternions,
    euler_to_quat,
    knn_blend_weights,
    pose_at,
    quat_slerp,
    quat_to_matrix,
    sample_blend_weights,
    stack_examples,
)


def _unit_quats(rng, shape):
    q = rng.standard_normal(shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def test_sample_blend_weights(key):
    W = np.asarray(sample_blend_weights(key, 5, 200, concentration=0.5, max_active=3))
    assert W.shape == (200, 5)
    np.testing.assert_allclose(W[:5], np.eye(5))
    np.testing.assert_allclose(W.sum(1), 1.0, atol=1e-12)
    assert W.min() >= 0.0 and ((W[5:] > 0).sum(1) <= 3).all()
    with pytest.raises(ValueError, match="n_samples"):
        sample_blend_weights(key, 5, 3)


def _knn_reference(q, P, W, k):
    d = np.linalg.norm(P - q, axis=1)
    idx = np.argsort(d, kind="stable")[:k]
    dk = d[idx]
    if dk[0] == 0:
        return W[idx[0]]
    w = 1 / dk - 1 / dk[-1]
    w = w / w.sum()
    return w @ W[idx]


def test_knn_weights_against_reference_and_exact_at_examples(key, rng):
    E, S = 4, 300
    W = np.asarray(sample_blend_weights(key, E, S))
    P = rng.standard_normal((S, 2))
    knn = jax.jit(knn_blend_weights, static_argnames="k")
    for q in rng.standard_normal((10, 2)):
        r = knn(jnp.asarray(q), jnp.asarray(P), jnp.asarray(W), k=6)
        np.testing.assert_allclose(r.weights, _knn_reference(q, P, W, 6), atol=1e-12)
        assert float(jnp.sum(r.weights)) == pytest.approx(1.0, abs=1e-12)
        assert float(jnp.sum(r.sample_weights)) == pytest.approx(1.0, abs=1e-12)
    for e in range(E):  # at an example's own parameter: exactly that example
        r = knn(jnp.asarray(P[e]), jnp.asarray(P), jnp.asarray(W), k=6)
        np.testing.assert_array_equal(r.weights, np.eye(E)[e])
    # jit + vmap over queries
    Q = jnp.asarray(rng.standard_normal((7, 2)))
    f = jax.jit(jax.vmap(lambda q: knn_blend_weights(q, jnp.asarray(P), jnp.asarray(W), 6).weights))
    np.testing.assert_allclose(
        f(Q), [_knn_reference(np.asarray(q), P, W, 6) for q in Q], atol=1e-12
    )


def test_blend_quaternions(rng):
    q = jnp.asarray(_unit_quats(rng, (3, 5)))
    np.testing.assert_allclose(blend_quaternions(q, jnp.asarray([0.0, 1.0, 0.0])), q[1], atol=1e-15)
    # sign invariance (q and −q are the same rotation)
    flipped = q.at[0].multiply(-1.0)
    w = jnp.asarray([0.3, 0.5, 0.2])
    np.testing.assert_allclose(
        quat_to_matrix(blend_quaternions(flipped, w)),
        quat_to_matrix(blend_quaternions(q, w)),
        atol=1e-12,
    )
    # two quaternions, equal weights = slerp midpoint
    mid = blend_quaternions(q[:2], jnp.asarray([0.5, 0.5]))
    ref = quat_slerp(q[0], q[1], jnp.full((5,), 0.5))
    np.testing.assert_allclose(quat_to_matrix(mid), quat_to_matrix(ref), atol=1e-12)


def _examples(rng, E=3, T=(10, 14, 8), J=4):
    rots = [_unit_quats(rng, (t, J)) for t in T[:E]]
    roots = [rng.standard_normal((t, 3)) for t in T[:E]]
    N = 12
    warps = np.stack([np.linspace(0, t - 1, N) for t in T[:E]])
    return stack_examples(rots, roots, jnp.asarray(warps)), rots, roots


def test_one_hot_blend_reproduces_example(rng):
    ex, rots, roots = _examples(rng)
    assert isinstance(ex, ExampleSet) and ex.rotations.shape == (3, 14, 4, 4)
    for e in range(3):
        w = jnp.eye(3)[e]
        for u in (0.0, 11.0):
            q, r = blend_pose(ex, w, jnp.asarray(u))
            f = 0 if u == 0 else len(rots[e]) - 1
            np.testing.assert_allclose(quat_to_matrix(q), quat_to_matrix(rots[e][f]), atol=1e-12)
            np.testing.assert_allclose(r, roots[e][f], atol=1e-12)
    # fractional times interpolate between neighbouring frames
    q, r = pose_at(ex, jnp.asarray([2.5, 0.0, 7.0]))
    np.testing.assert_allclose(r[0], 0.5 * (roots[0][2] + roots[0][3]), atol=1e-12)
    jq, jr = jax.jit(blend_pose)(ex, jnp.asarray([0.2, 0.3, 0.5]), jnp.asarray(4.3))
    eq, er = blend_pose(ex, jnp.asarray([0.2, 0.3, 0.5]), jnp.asarray(4.3))
    np.testing.assert_allclose(jq, eq, atol=1e-12)
    np.testing.assert_allclose(jr, er, atol=1e-12)


def test_blend_of_small_rotations_is_close_to_average_angle():
    # rotations about one axis blend to the weighted angle (small angles: nearly exact)
    ang = jnp.asarray([[10.0], [20.0], [40.0]])
    q = euler_to_quat(ang, "Z")
    w = jnp.asarray([0.5, 0.25, 0.25])
    blended = blend_quaternions(q, w)
    ref = euler_to_quat(jnp.asarray([20.0]), "Z")
    assert float(jnp.abs(jnp.sum(blended * ref))) > np.cos(np.deg2rad(0.1) / 2)
