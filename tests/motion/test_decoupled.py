"""The synthesis API (Ha & Han §3): a pure step under lax.scan, parameters changing every
frame, and the §3.2 re-placement against exact re-sampling."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TOY_NAMES as NAMES
from helpers import TOY_OFFSETS as OFFSETS
from helpers import TOY_PARENTS as PARENTS
from helpers import toy_clips as _clips

import fxspace as fx
from fxspace.motion import (
    build_spaces,
    exact_upper_params,
    init_state,
    replace_samples,
    synthesize,
    synthesize_step,
    upper_body_mask,
)


def _spaces(posture_transfer=0.5, n_samples=80, k_replace=6, upper_joint=7):
    rng = np.random.default_rng(1)
    qL, rL = _clips(rng, 4, 20, 0.4)
    qU, rU = _clips(rng, 5, 16, 0.6)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.7, 0.9, 0.8, 1.0)])
    exL = fx.motion.stack_examples(list(qL), list(rL), wl)
    exU = fx.motion.stack_examples(list(qU), list(rU), wu)
    lam = np.linspace(0, 15, 20)
    return build_spaces(
        exL, exU, lam, PARENTS, OFFSETS,
        mask=upper_body_mask(PARENTS, NAMES), spine=4, lower_joint=3, lower_dims=(0, 2),
        lower_time=19.0, upper_joint=upper_joint, upper_time=8.0, key=jax.random.PRNGKey(0),
        n_samples=n_samples, knn_k=4, k_replace=k_replace, posture_transfer=posture_transfer,
    )  # fmt: skip


@pytest.fixture(scope="module")
def sp():
    return _spaces()


# one compilation each, shared by the tests (the spaces' arrays are traced, not static)
_exact = exact_upper_params
_replace = replace_samples
_step = synthesize_step
_synth = synthesize


def test_replacement_matches_exact_resampling(sp):
    w_new = jnp.asarray([0.1, 0.2, 0.6, 0.1])
    exact = _exact(sp, w_new)
    repl = _replace(sp, w_new)
    stale = sp.upper_params
    e_repl = np.linalg.norm(np.asarray(repl - exact), axis=1)
    e_stale = np.linalg.norm(np.asarray(stale - exact), axis=1)
    # §3.2 as printed (the default): one rotation about the root. Here the new lower body
    # also shifts the samples, which a rotation cannot follow: re-placed samples stay well
    # under half the stale samples' error (measured: max 7.9 cm, stale ≈ 7 cm mean)
    assert sp.replace == "rotation"
    assert e_stale.mean() > 0.03
    assert e_repl.mean() < 0.5 * e_stale.mean()
    # the rigid option (rotation + translation) follows the shift: within 2.5 cm of exact
    # re-sampling (mean ≈ 4 mm), under a tenth of the stale samples' mean error
    rigid = dataclasses.replace(sp, replace="rigid")
    e_rigid = np.linalg.norm(np.asarray(_replace(rigid, w_new) - exact), axis=1)
    assert e_rigid.max() < 0.025 and e_rigid.mean() < 0.1 * e_stale.mean()
    # for the initial lower blend the stored ṗ are exact and Horn returns the identity
    np.testing.assert_allclose(_replace(sp, sp.lower_w0), stale, atol=1e-5)
    # the heading-relative splice at posture transfer 1: the upper body keeps its
    # heading-relative orientation, so a new lower body moves every sample by one
    # translation — Horn's rigid option recovers it (float32 round-off)
    s1 = dataclasses.replace(
        sp, posture_transfer=jnp.ones_like(sp.posture_transfer), splice="heading", replace="rigid"
    )
    s1 = dataclasses.replace(s1, upper_params=_exact(s1, s1.lower_w0))
    np.testing.assert_allclose(_replace(s1, w_new), _exact(s1, w_new), atol=2e-5)


def test_step_is_pure_and_scan_matches_a_loop(sp):
    F = 8
    pl = np.linspace(np.asarray(sp.lower_params[0]), np.asarray(sp.lower_params[2]), F)
    pu = np.tile(np.asarray(sp.upper_params[3]), (F, 1))
    _, poses, clocks = _synth(sp, jnp.asarray(pu), jnp.asarray(pl), 0.5)
    st = init_state(sp, pl[0])
    for f in range(F):
        np.testing.assert_allclose(clocks[f], [st.t_lower, st.t_upper], atol=1e-5)
        st2, pose = _step(sp, st, pu[f], pl[f], 0.5, 1.0)
        np.testing.assert_allclose(pose.rotations, poses.rotations[f], atol=1e-5)
        # same inputs → same outputs (pure)
        np.testing.assert_array_equal(_step(sp, st, pu[f], pl[f], 0.5, 1.0)[0].t_lower, st2.t_lower)
        st = st2
    assert np.all(np.diff(np.asarray(clocks), axis=0) >= -1e-6)
    # re-placement runs only when the lower parameter changes
    st = init_state(sp, sp.lower_params[0])
    same, _ = _step(sp, st, sp.upper_params[0], sp.lower_params[0], 0.5, 1.0)
    np.testing.assert_array_equal(same.upper_params, st.upper_params)
    moved, _ = _step(sp, st, sp.upper_params[0], sp.lower_params[5], 0.5, 1.0)
    w5 = fx.motion.knn_blend_weights(sp.lower_params[5], sp.lower_params, sp.lower_weights, 4)
    np.testing.assert_allclose(moved.upper_params, _replace(sp, w5.weights), atol=1e-5)
    assert not np.allclose(moved.upper_params, st.upper_params, atol=1e-3)


def test_target_reaching_with_replacement(sp):
    # a hand target reachable with the new lower body: k-NN over re-placed samples reaches it
    # nearly as well as over exactly re-sampled ones, and better than over the stale samples
    wl = jnp.asarray([0.0, 0.1, 0.3, 0.6])
    rigid = dataclasses.replace(sp, replace="rigid")
    sets = jnp.stack([_replace(sp, wl), sp.upper_params, _exact(sp, wl), _replace(rigid, wl)])
    wq = jnp.asarray(np.random.default_rng(3).dirichlet(np.ones(5), 6))

    @jax.jit
    def errors(sp, sets, wq):
        def one(w):
            target = fx.motion.upper_param_of(sp, wl, w)

            def reach(P):
                wu = fx.motion.knn_blend_weights(target, P, sp.upper_weights, 4).weights
                return jnp.linalg.norm(fx.motion.upper_param_of(sp, wl, wu) - target)

            return jax.vmap(reach)(sets)

        return jax.vmap(one)(wq).mean(axis=0)

    repl, stale, exact, repl_rigid = np.asarray(errors(sp, sets, wq))
    # the default (§3.2's rotation; measured 3.6 cm vs stale 11.0 cm, exact 2.4 cm) and
    # the rigid option (nearly exact here, where the new lower body shifts the samples)
    assert repl < 0.5 * stale
    assert repl_rigid < stale and repl_rigid <= exact + 5e-3


def test_direct_weights_upper_space(sp):
    s = dataclasses.replace(sp, upper_joint=-1)
    st = init_state(s, s.lower_params[0])
    p1 = _step(s, st, jnp.asarray([1.0, 0, 0, 0, 0]), s.lower_params[0], 0.5, 1.0)[1]
    p2 = _step(s, st, jnp.asarray([0, 0, 0, 0, 2.0]), s.lower_params[0], 0.5, 1.0)[1]
    mask = np.asarray(s.mask)
    # an upper joint below the splice joint copies example 0 / example 4 at the upper clock
    np.testing.assert_allclose(p1.rotations[7], s.upper.rotations[0, 0, 7], atol=1e-6)
    np.testing.assert_allclose(p2.rotations[7], s.upper.rotations[4, 0, 7], atol=1e-6)
    np.testing.assert_allclose(p1.rotations[~mask], p2.rotations[~mask], atol=1e-7)


@pytest.mark.parametrize("wrap", [False, True])
def test_clock_alignment_bounded_by_the_fastest_example(sp, wrap):
    """Eqs. 2–3 pull the two clocks together; the default bound (issue 47.1) lets neither
    advance past the fastest example of its own set at its phase (`clock_bounds`), so
    a body half never plays faster than some capture of it — but it may run faster than
    its own blend's eq.-(1) step, so α keeps its effect. The pair stays aligned
    (``T_L = λ⁻¹(T_U)``); ``inf`` gives eqs. 2–3 as printed (`align_clocks`)."""
    from fxspace.motion._synthesis import SynthState, _advance

    wL = sp.lower_w0
    wU = jnp.zeros(sp.upper.warps.shape[0]).at[0].set(1.0)
    lam = np.asarray(sp.lam)
    rushed = 0
    for tl0, tu0 in ((8.0, 1.0), (2.0, 12.0), (6.0, float(np.interp(6.0, np.arange(20), lam)))):
        st = SynthState(jnp.asarray(tl0), jnp.asarray(tu0), sp.lower_params[0],
                        sp.upper_params, wL)  # fmt: skip
        dl = float(fx.motion.advance_clock(st.t_lower, sp.lower.warps, wL, 1.0, sp.min_slope))
        du = float(fx.motion.advance_clock(st.t_upper, sp.upper.warps, wU, 1.0, sp.min_slope))
        # the fastest example of each set at this phase, by hand
        slopes_l = np.diff(np.asarray(sp.lower.warps), axis=1)[:, min(int(tl0), 18)]
        slopes_u = np.diff(np.asarray(sp.upper.warps), axis=1)[:, min(int(tu0), 14)]
        bl, bu = 1.0 / slopes_l.min(), 1.0 / slopes_u.min()
        np.testing.assert_allclose(fx.motion.clock_bounds(sp, st.t_lower, st.t_upper),
                                   [bl, bu], rtol=1e-5)  # fmt: skip
        tl, tu, _ = _advance(sp, st, wL, wU, 0.5, 1.0, wrap)
        tl, tu = float(tl), float(tu)
        assert tl - tl0 <= bl + 1e-5 and tu - tu0 <= bu + 1e-5
        rushed += (tl - tl0 > dl + 1e-3) or (tu - tu0 > du + 1e-3)
        assert tl == pytest.approx(float(fx.motion.invert_curve(sp.lam, tu)), abs=1e-4)
        free = dataclasses.replace(sp, max_clock_rate=float("inf"))
        tl_p, tu_p, _ = _advance(free, st, wL, wU, 0.5, 1.0, wrap)
        if not wrap:
            ref = fx.motion.align_clocks(jnp.asarray(tl0 + dl), jnp.asarray(tu0 + du), sp.lam, 0.5)
            np.testing.assert_allclose([tl_p, tu_p], ref, atol=1e-5)
        if tl0 == 8.0:  # the upper clock far behind: as printed, eq. 2 rushes it forward
            assert float(tu_p) - tu0 > bu + 0.5  # (the bound holds it to bu, above)
    assert rushed  # a clock did pass its own blend's step: the bound is not the old cap
    with pytest.raises(ValueError, match="max_clock_rate"):
        _spaces_with(max_clock_rate=0.0)
    # eqs. 2–3 as printed are a valid setting (issue 47.1: inf was refused as "not finite")
    assert _spaces_with(max_clock_rate=float("inf")).max_clock_rate == float("inf")


def test_alpha_moves_the_lower_tempo_under_the_default_bound(sp):
    """α is alive (issue 47.1): with an upper blend of a faster tempo, the lower cycle
    rate that eqs. 1–3 give (`clock_cycle_rate`) rises from the lower blend's own tempo
    at α = 1 towards the upper blend's at α = 0 — up to the fastest lower example (the
    bound), where eqs. 2–3 as printed would go on to the upper tempo. Under the old cap
    (each clock at most its own eq.-1 step) it stayed at the lower blend's tempo."""
    wL = sp.lower_w0  # the reference lower example: 19 reference frames per cycle
    wU = jnp.zeros(sp.upper.warps.shape[0]).at[1].set(1.0)  # upper example 1: C' = 0.7
    r1 = float(fx.motion.clock_cycle_rate(sp, wL, wU, 1.0, 400))
    r0 = float(fx.motion.clock_cycle_rate(sp, wL, wU, 0.0, 400))
    r_half = float(fx.motion.clock_cycle_rate(sp, wL, wU, 0.5, 400))
    assert r1 == pytest.approx(1 / 19, rel=0.02)  # the lower blend's own tempo
    assert r0 == pytest.approx(1 / 0.8 / 19, rel=0.02)  # the fastest lower example (C' 0.8)
    assert r1 < r_half <= r0
    free = dataclasses.replace(sp, max_clock_rate=float("inf"))
    r0_free = float(fx.motion.clock_cycle_rate(free, wL, wU, 0.0, 400))
    assert r0_free == pytest.approx(1 / (15 * 0.7), rel=0.03)  # the upper tempo, as printed


def _spaces_with(**kw):
    rng = np.random.default_rng(1)
    qL, rL = _clips(rng, 2, 20, 0.4)
    qU, rU = _clips(rng, 2, 16, 0.6)
    exL = fx.motion.stack_examples(list(qL), list(rL), np.stack([np.arange(20.0)] * 2))
    exU = fx.motion.stack_examples(list(qU), list(rU), np.stack([np.arange(16.0)] * 2))
    return build_spaces(
        exL, exU, np.linspace(0, 15, 20), PARENTS, OFFSETS,
        mask=upper_body_mask(PARENTS, NAMES), spine=4, lower_joint=3, lower_dims=(0, 2),
        lower_time=19.0, upper_joint=7, upper_time=8.0, key=jax.random.PRNGKey(0),
        n_samples=20, knn_k=2, k_replace=6, **kw,
    )  # fmt: skip
