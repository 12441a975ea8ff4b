"""Horn's absolute orientation: exact recovery, reflections, weights, jit/vmap/grad."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import check_grad
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.motion import apply_rigid


@pytest.mark.parametrize("seed", range(5))
def test_exact_recovery(seed):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.standard_normal(3) * 3
    src = rng.standard_normal((int(rng.integers(3, 30)), 3))
    dst = src @ R.T + t
    Rh, th = fx.absolute_orientation(src, dst)
    np.testing.assert_allclose(Rh, R, atol=1e-10)
    np.testing.assert_allclose(th, t, atol=1e-10)


def _kabsch_proper(src, dst):
    """Reference: SVD solution with the det correction (always a proper rotation)."""
    s0, d0 = src - src.mean(0), dst - dst.mean(0)
    U, _, Vt = np.linalg.svd(s0.T @ d0)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, dst.mean(0) - R @ src.mean(0)


def test_reflection_is_never_returned(rng):
    src = rng.standard_normal((12, 3))
    dst = (src * np.asarray([1.0, 1.0, -1.0])) @ Rotation.random(random_state=3).as_matrix().T
    R, t = fx.absolute_orientation(src, dst)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    Rr, tr = _kabsch_proper(src, dst)
    res = lambda R, t: np.sum((src @ np.asarray(R).T + np.asarray(t) - dst) ** 2)  # noqa: E731
    assert res(R, t) == pytest.approx(res(Rr, tr), rel=1e-10)


def test_noisy_matches_reference_and_weights(rng):
    R0 = Rotation.random(random_state=5).as_matrix()
    src = rng.standard_normal((40, 3))
    dst = src @ R0.T + 0.05 * rng.standard_normal((40, 3))
    R, t = fx.absolute_orientation(src, dst)
    Rr, tr = _kabsch_proper(src, dst)
    np.testing.assert_allclose(R, Rr, atol=1e-10)
    np.testing.assert_allclose(t, tr, atol=1e-10)
    # weights: integer weights = repeated points
    w = rng.integers(1, 4, size=40)
    Rw, tw = fx.absolute_orientation(src, dst, weights=w.astype(float))
    Rr2, tr2 = _kabsch_proper(np.repeat(src, w, 0), np.repeat(dst, w, 0))
    np.testing.assert_allclose(Rw, Rr2, atol=1e-10)
    np.testing.assert_allclose(tw, tr2, atol=1e-10)


def test_jit_vmap_grad(rng):
    src = jnp.asarray(rng.standard_normal((3, 8, 3)))
    Rs = Rotation.random(3, random_state=1).as_matrix()
    dst = jnp.einsum("bij,bkj->bki", Rs, src) + 1.0
    batched = jax.jit(jax.vmap(fx.absolute_orientation))(src, dst)
    for k in range(3):
        R, t = fx.absolute_orientation(src[k], dst[k])
        np.testing.assert_allclose(batched.R[k], R, atol=1e-10)
        np.testing.assert_allclose(batched.t[k], t, atol=1e-10)
    np.testing.assert_allclose(
        apply_rigid(fx.absolute_orientation(src[0], dst[0]), src[0]), dst[0], atol=1e-10
    )
    d_noisy = dst[0] + 0.1 * jnp.asarray(rng.standard_normal((8, 3)))

    def f(x):
        tf = fx.absolute_orientation(x, d_noisy)
        return jnp.sum((apply_rigid(tf, x) - d_noisy) ** 2)

    check_grad(jax.jit(f), src[0], rng)


def test_errors():
    with pytest.raises(ValueError, match=r"\(k, 3\)"):
        fx.absolute_orientation(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="at least 3"):
        fx.absolute_orientation(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="weights"):
        fx.absolute_orientation(np.zeros((4, 3)), np.zeros((4, 3)), weights=np.ones(3))


def test_absolute_rotation_matches_scipy_align_vectors():
    """Rotation about the origin only (Ha & Han §3.2): the same R as scipy's
    Rotation.align_vectors (Kabsch without centring), and exact on rotated points."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    src = rng.normal(size=(12, 3))
    R_true = Rotation.from_rotvec([0.3, -0.5, 0.9]).as_matrix()
    dst = src @ R_true.T
    np.testing.assert_allclose(fx.motion.absolute_rotation(src, dst), R_true, atol=1e-10)
    noisy = dst + rng.normal(0, 0.05, dst.shape) + 0.3  # a shift it must not absorb
    w = rng.uniform(0.5, 2.0, 12)
    ref, _ = Rotation.align_vectors(noisy, src, weights=w)
    np.testing.assert_allclose(fx.motion.absolute_rotation(src, noisy, w), ref.as_matrix(),
                               atol=1e-9)  # fmt: skip
    R = np.asarray(fx.motion.absolute_rotation(src, noisy))
    assert abs(np.linalg.det(R) - 1.0) < 1e-12
