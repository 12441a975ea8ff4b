"""Ha & Han §3.1 as printed: eq. (1) ΔT = (Σ w_i dT/dC_i) Δt, eqs. (2)–(3)
T_U ← α λ(T_L) + (1−α) T_U, T_L ← λ⁻¹(T_U); hand-computed numbers and a numpy reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.motion import advance_clock, advance_clock_duration, align_clocks, invert_curve


def test_eq1_weighted_mean_of_inverse_slopes():
    # C_1(T) = 0.5 T, C_2(T) = 2 T: dT/dC = 2 and 0.5; equal weights → 1.25 Δt (the case)
    warps = jnp.asarray([np.arange(10) * 0.5, np.arange(10) * 2.0])
    w = jnp.asarray([0.5, 0.5])
    assert float(fx.motion.advance_clock(jnp.asarray(3.0), warps, w, 1.0)) == pytest.approx(1.25)
    assert float(advance_clock(jnp.asarray(3.0), warps, w, 0.5)) == pytest.approx(0.625)
    # weights (0.2, 0.8): 0.2·2 + 0.8·0.5 = 0.8
    w2 = jnp.asarray([0.2, 0.8])
    assert float(advance_clock(jnp.asarray(7.5), warps, w2, 1.0)) == pytest.approx(0.8)
    # the old duration-averaging option is a different (harmonic) mean: 1 / (0.5·0.5 + 0.5·2)
    assert float(advance_clock_duration(jnp.asarray(3.0), warps, w, 1.0)) == pytest.approx(0.8)


def test_eq1_piecewise_slope_and_reference(rng):
    # a piecewise-linear warp: slope on the segment that holds T; against numpy
    warps = np.stack([np.cumsum(np.r_[0, rng.uniform(0.3, 3.0, 19)]) for _ in range(3)])
    w = rng.dirichlet(np.ones(3))
    for T in (0.0, 4.3, 11.9, 18.5):
        i = min(int(np.floor(T)), 18)
        ref = np.sum(w / (warps[:, i + 1] - warps[:, i]))
        got = advance_clock(jnp.asarray(T), jnp.asarray(warps), jnp.asarray(w), 1.0)
        assert float(got) == pytest.approx(ref, rel=1e-6)
    # a flat piece is floored at min_slope: dT/dC ≤ 1/min_slope
    flat = jnp.zeros((1, 10))
    assert float(advance_clock(jnp.asarray(2.0), flat, jnp.ones(1), 1.0, 0.05)) == pytest.approx(20)


def test_eqs_2_3_hand_computed():
    lam = jnp.asarray(2.0 * np.arange(10))  # λ(T) = 2T
    tl, tu = align_clocks(jnp.asarray(3.0), jnp.asarray(4.0), lam, 0.5)  # eq. (2) as printed
    assert (float(tl), float(tu)) == pytest.approx((2.5, 5.0))
    tl, tu = fx.motion.align_clocks(jnp.asarray(3.0), jnp.asarray(4.0), lam, 1.0)
    assert (float(tl), float(tu)) == pytest.approx((3.0, 6.0))  # upper follows lower
    tl, tu = align_clocks(jnp.asarray(3.0), jnp.asarray(4.0), lam, 0.0)
    assert (float(tl), float(tu)) == pytest.approx((2.0, 4.0))  # lower reset from upper
    # non-linear λ sampled at 0,1,2,3: T_L = 1.5 → λ = 2; α = ¼: T_U = ½ + ¾·5 = 4.25;
    # λ⁻¹(4.25) on the segment [3, 6] = 2 + 1.25/3
    lam2 = jnp.asarray([0.0, 1.0, 3.0, 6.0])
    tl, tu = align_clocks(jnp.asarray(1.5), jnp.asarray(5.0), lam2, 0.25)
    assert float(tu) == pytest.approx(4.25)
    assert float(tl) == pytest.approx(2 + 1.25 / 3)


def test_invert_curve_against_numpy(rng):
    lam = np.cumsum(np.r_[0.0, rng.uniform(0.1, 2.0, 30)])
    ys = rng.uniform(lam[0], lam[-1], 50)
    got = jax.vmap(lambda y: invert_curve(jnp.asarray(lam), y))(jnp.asarray(ys))
    np.testing.assert_allclose(got, np.interp(ys, lam, np.arange(lam.size)), rtol=1e-6)
    # flat piece: the last preimage, so λ⁻¹ is non-decreasing
    flat = jnp.asarray([0.0, 1.0, 1.0, 2.0])
    assert float(invert_curve(flat, jnp.asarray(1.0))) == 2.0
    assert float(invert_curve(flat, jnp.asarray(-5.0))) == 0.0
    assert float(invert_curve(flat, jnp.asarray(9.0))) == 3.0


@pytest.mark.parametrize("alpha", [0.0, 0.3, 0.5, 1.0])
def test_time_never_runs_backwards(alpha, rng):
    N = 40
    warps_l = jnp.asarray(
        np.stack([np.cumsum(np.r_[0, rng.uniform(0.2, 2, N - 1)]) for _ in range(3)])
    )
    warps_u = jnp.asarray(
        np.stack([np.cumsum(np.r_[0, rng.uniform(0.2, 2, 29)]) for _ in range(2)])
    )
    lam = jnp.asarray(np.cumsum(np.r_[0, rng.uniform(0.0, 1.5, N - 1)]))  # flat pieces too
    wl, wu = jnp.asarray(rng.dirichlet(np.ones(3))), jnp.asarray(rng.dirichlet(np.ones(2)))

    def step(c, _):
        tl = jnp.minimum(c[0] + advance_clock(c[0], warps_l, wl), N - 1.0)
        tu = c[1] + advance_clock(c[1], warps_u, wu)
        tl, tu = align_clocks(tl, tu, lam, alpha)
        return jnp.stack([tl, tu]), jnp.stack([tl, tu])

    _, cs = jax.lax.scan(step, jnp.stack([jnp.asarray(0.0), lam[0]]), None, length=60)
    cs = np.asarray(cs)
    assert np.all(np.diff(cs[:, 0]) >= -1e-12) and np.all(np.diff(cs[:, 1]) >= -1e-12)
    assert cs[-1, 0] > cs[0, 0]
