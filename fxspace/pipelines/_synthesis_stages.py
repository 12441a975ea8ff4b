"""The measured stages of a ``parametric_synthesis`` set-up: target errors (``targets``),
eq. 1's registration (``timewarp``), a scripted session (``session``), and the
synthesised clips with the per-step timing."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace._progress import progress
from fxspace.io import write_bvh
from fxspace.pipelines._synthesis_config import Config


def _timeit(f, *args, repeats: int = 5) -> float:
    jax.block_until_ready(f(*args))
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def _clip(sp, up, lp, alpha, n_ref: int):
    """Synthesise until the lower clock reaches the reference end; returns poses and clocks."""
    F = 3 * n_ref
    up = jnp.broadcast_to(jnp.asarray(up), (F,) + jnp.shape(up)[-1:]) if up.ndim == 1 else up
    lp = jnp.broadcast_to(jnp.asarray(lp), (F,) + jnp.shape(lp)[-1:]) if lp.ndim == 1 else lp
    _, poses, clocks = _synth(sp, up, lp, alpha)
    c = np.asarray(clocks)
    done = np.nonzero(c[:, 0] >= n_ref - 1 - 1e-6)[0]
    n = int(done[0]) + 1 if done.size else F
    return np.asarray(poses.rotations[:n]), np.asarray(poses.root[:n]), c[:n]


_synth = jax.jit(M.synthesize)


# --------------------------------------------------------------------- stage: targets
def _queries(st: M.Setup, cfg: Config, key):
    sp = st.spaces
    EL, EU = sp.lower.warps.shape[0], sp.upper.warps.shape[0]
    kq1, kq2 = jax.random.split(jax.random.fold_in(key, 1))
    nq = cfg.synth.n_queries
    wq_l = M.sample_blend_weights(kq1, EL, EL + nq, cfg.space.concentration)[EL:]
    wq_u = M.sample_blend_weights(kq2, EU, EU + nq, cfg.space.concentration)[EU:]
    qL = jax.jit(jax.vmap(lambda w: M.lower_param_of(sp, w)))(wq_l)
    return qL, wq_u


def _stage_targets(st: M.Setup, cfg: Config, qL, wq_u) -> dict:
    """Target errors of k-NN interpolation; upper ones with vs without the §3.2
    re-placement (stale samples) and against exact re-sampling (Fig. 2's problem)."""
    sp = st.spaces
    knnL = jax.jit(
        lambda p: M.knn_blend_weights(p, sp.lower_params, sp.lower_weights, sp.knn_k).weights
    )
    exact_f = jax.jit(lambda w: M.exact_upper_params(sp, w))
    replace_f = jax.jit(lambda w: M.replace_samples(sp, w))
    # the other §3.2 variant, for the measured difference (rotation vs rotation + shift)
    other = "rigid" if sp.replace == "rotation" else "rotation"
    other_f = jax.jit(lambda w: M.replace_samples(dataclasses.replace(sp, replace=other), w))

    @jax.jit
    def reach(wL, pU, params):
        wU = M.knn_blend_weights(pU, params, sp.upper_weights, sp.knn_k).weights
        return jnp.linalg.norm(M.upper_param_of(sp, wL, wU) - pU)

    err_l, rows = [], []
    for i in progress(range(len(qL)), f"{st.name}: targets", total=len(qL)):
        wL = knnL(qL[i])
        err_l.append(float(np.linalg.norm(np.asarray(M.lower_param_of(sp, wL) - qL[i]))))
        if sp.upper_joint >= 0:
            exact, repl = exact_f(wL), replace_f(wL)
            pU = M.upper_param_of(sp, wL, wq_u[i])  # a reachable hand target
            rows.append(
                [
                    float(reach(wL, pU, repl)),
                    float(reach(wL, pU, sp.upper_params)),
                    float(reach(wL, pU, exact)),
                    float(jnp.linalg.norm(repl - exact, axis=1).mean()),
                    float(jnp.linalg.norm(repl - exact, axis=1).max()),
                    float(jnp.linalg.norm(sp.upper_params - exact, axis=1).mean()),
                    float(jnp.linalg.norm(other_f(wL) - exact, axis=1).mean()),
                ]
            )
    m = {
        "lower_target_error_mean_m": float(np.mean(err_l)),
        "lower_target_error_max_m": float(np.max(err_l)),
    }
    if rows:
        r = np.asarray(rows)
        m.update(
            splice=sp.splice,
            posture_transfer=float(sp.posture_transfer),
            k_replace=sp.k_replace,
            upper_target_error_replaced_mean_m=float(r[:, 0].mean()),
            upper_target_error_stale_mean_m=float(r[:, 1].mean()),
            upper_target_error_resampled_mean_m=float(r[:, 2].mean()),
            replacement_error_mean_m=float(r[:, 3].mean()),
            replacement_error_max_m=float(r[:, 4].max()),
            stale_sample_error_mean_m=float(r[:, 5].mean()),
            replace=sp.replace,
            **{f"replacement_error_{other}_mean_m": float(r[:, 6].mean())},
        )
    return m


# --------------------------------------------------------------------- stage: timewarp
def _examples_X(st: M.Setup, ex) -> list[np.ndarray]:
    sk = st.skeleton
    return [
        np.asarray(
            M.fk_arrays(
                sk.parents,
                np.asarray(sk.offsets),
                np.asarray(ex.root[i, : int(ex.lengths[i])]),
                np.asarray(ex.rotations[i, : int(ex.lengths[i])]),
            )[0]
        )
        for i in range(ex.warps.shape[0])
    ]


def _jitter(X: np.ndarray, rate: float) -> float:
    """Mean joint acceleration magnitude (m/s²): ``|X[t+1] − 2X[t] + X[t−1]|·rate²``."""
    return float(np.linalg.norm(np.diff(X, 2, axis=0), axis=-1).mean() * rate**2)


def _stage_timewarp(st: M.Setup) -> tuple[dict, dict]:
    """Eq. 1's registration within one example set (``registration_*`` metrics; not the paper's
    Fig. 3, which is `_fig3_clocks`): 50/50 blends of each set's reference example with each
    other one, played over the reference clip with the registration (``C_i``, eq. 1's warps)
    and without any time-warping (frame ``T`` of every example blended with frame ``T``);
    foot sliding in contact and joint jitter of both, the examples' own as the floor. For
    the mood walk the joy/sad walks (different tempi) are blended as well. Returns
    ``(metrics, toe-height curves of the first set)``."""
    sp, sk = st.spaces, st.skeleton
    sets = [("lower", sp.lower)] + ([("upper", sp.upper)] if sp.upper_joint < 0 else [])
    toe = st.feet[0]
    out: dict = {"warped_slide": [], "plain_slide": [], "warped_jitter": [], "plain_jitter": []}
    curves: dict = {"warped": {}, "plain": {}}
    for set_name, ex in sets:
        N = int(ex.warps.shape[1])
        T = jnp.arange(N, dtype=sp.lam.dtype)
        plain = ex._replace(warps=jnp.minimum(T[None], (ex.lengths[:, None] - 1).astype(T.dtype)))

        @jax.jit
        def traj(ex, w, T=T):
            q, r = jax.vmap(lambda t: M.blend_pose(ex, w, t))(T)
            return M.fk_arrays(sk.parents, sp.offsets, r, q)[0]

        E = int(ex.warps.shape[0])
        for i in range(1, min(E, 7)):
            w = jnp.zeros(E, sp.lam.dtype).at[0].set(0.5).at[i].set(0.5)
            for kind, e in (("warped", ex), ("plain", plain)):
                X = np.asarray(traj(e, w))
                out[f"{kind}_slide"].append(M.foot_sliding(X, st.feet, sk.rate))
                out[f"{kind}_jitter"].append(_jitter(X, sk.rate))
                if i <= 3 and set_name == sets[-1][0]:
                    curves[kind][f"{set_name} M1+M{i + 1}"] = X[:, toe, 1]
    Xe = _examples_X(st, sp.lower) + (_examples_X(st, sp.upper) if len(sets) > 1 else [])
    curves["examples"] = {f"example {i + 1}": x[:, toe, 1] for i, x in enumerate(Xe[-2:])}
    m = {f"registration_{k}_mean": float(np.nanmean(v)) for k, v in out.items()}
    m["registration_foot_slide_examples_mean"] = float(
        np.nanmean([M.foot_sliding(X, st.feet, sk.rate) for X in Xe])
    )
    m["registration_jitter_examples_mean"] = float(np.mean([_jitter(X, sk.rate) for X in Xe]))
    m["registration_units"] = (
        "foot slide m/s while in contact; jitter m/s^2 (mean joint acceleration)"
    )
    m["registration_blends"] = "50/50: reference + each other example of " + " and ".join(
        n for n, _ in sets
    )
    return m, curves


# --------------------------------------------------------------------- stage: session
def _schedule(controls: dict, seconds: float, every: float, seed: int) -> list:
    rng = np.random.default_rng(seed)
    n = int(np.ceil(seconds / every))
    return [
        (every * k, {c: float(rng.uniform(lo, hi)) for c, (lo, hi) in controls.items()})
        for k in range(n)
    ]


def _stage_session(st: M.Setup, cfg: Config, seed: int, run_dir: Path) -> dict:
    """The done-when check of issue 22 as numbers: a scripted continuous session with every
    control (turning included) changed every ``session_every_s``."""
    sy = cfg.synth
    table = M.session_turn_table(st)
    controls = M.session_controls(st, table)
    sched = _schedule(controls, sy.session_s, sy.session_every_s, seed)
    if st.spaces.upper_joint >= 0:  # hand raises: α = 1 keeps the walk's own tempo
        sched = [(t, {**c, "alpha": 1.0}) for t, c in sched]
    X, fps, _, poses = M.run_session(st, sched, sy.session_s, table=table)
    write_bvh(
        run_dir / f"{st.name}_session.bvh",
        dataclasses.replace(
            st.skeleton,
            root_translation=np.asarray(poses.root),
            rotations=np.asarray(poses.rotations),
        ),
        scale=st.scale,
    )
    sp = st.spaces
    Xe = _examples_X(st, sp.lower) + _examples_X(st, sp.upper)
    ex_step = max(float(np.linalg.norm(np.diff(x, axis=0), axis=-1).max()) for x in Xe)
    rs = np.linalg.norm(np.diff(X[:, 0], axis=0), axis=1)
    js = np.linalg.norm(np.diff(X, axis=0), axis=-1)
    slide = M.foot_sliding(X, st.feet, fps)
    floor = float(
        np.nanmean([M.foot_sliding(x, st.feet, fps) for x in Xe[: sp.lower.warps.shape[0]]])
    )
    return {
        "session_s": sy.session_s,
        "session_controls": {k: list(v) for k, v in controls.items()},
        "session_root_step_max_over_median": float(rs.max() / np.median(rs)),
        "session_joint_step_max_m": float(js.max()),
        "examples_joint_step_max_m": ex_step,
        "session_foot_slide_m_per_s": slide,
        "examples_foot_slide_m_per_s": floor,
        "session_foot_slide_ratio": slide / floor,
        "session_distance_m": float(np.linalg.norm(np.diff(X[:, 0, [0, 2]], axis=0), axis=1).sum()),
    }


# --------------------------------------------------------------------- clips, timing, figures
def _write(run_dir: Path, fname: str, st: M.Setup, q, r) -> None:
    mot = dataclasses.replace(st.skeleton, root_translation=r, rotations=q)
    write_bvh(run_dir / fname, mot, scale=st.scale)


def _clips_and_timing(st: M.Setup, cfg: Config, run_dir: Path, qL, wq_u) -> tuple[dict, dict]:
    """Synthesised clips (fixed parameters per α, a lower parameter steered through the
    clip), foot sliding, and the per-step cost with and without re-placement."""
    sp, sk, sy = st.spaces, st.skeleton, cfg.synth
    n_ref = int(sp.lam.shape[0])
    knnL = jax.jit(
        lambda p: M.knn_blend_weights(p, sp.lower_params, sp.lower_weights, sp.knn_k).weights
    )
    parametric = sp.upper_joint >= 0
    up0 = M.upper_param_of(sp, knnL(qL[0]), wq_u[0]) if parametric else jnp.asarray([0.5, 0.5])
    clocks, outs = {}, {}
    for a in sy.alphas + (sy.alpha,):
        q, r, c = _clip(sp, up0, qL[0], a, n_ref)
        clocks[a], outs[a] = (c[:, 0], c[:, 1]), (q, r)
    m: dict = {
        "clocks_monotone_all_alphas": bool(
            all(
                np.all(np.diff(u) >= -1e-9) and np.all(np.diff(v) >= -1e-9)
                for u, v in clocks.values()
            )
        )
    }
    q, r = outs[sy.alpha]
    _write(run_dir, f"{st.name}.bvh", st, q, r)
    X = np.asarray(M.fk_arrays(sk.parents, np.asarray(sk.offsets), r, q)[0])
    s = np.linspace(0.0, 1.0, 3 * n_ref)[:, None]
    steer = (1 - s) * np.asarray(qL[0]) + s * np.asarray(qL[1])
    qs, rs, _ = _clip(sp, up0, jnp.asarray(steer), sy.alpha, n_ref)
    _write(run_dir, f"{st.name}_steer.bvh", st, qs, rs)
    m["frames_synthesised"] = int(q.shape[0])
    m["foot_sliding_m_per_s"] = M.foot_sliding(X, st.feet, sk.rate)
    m["foot_sliding_examples_m_per_s"] = float(
        np.nanmean([M.foot_sliding(x, st.feet, sk.rate) for x in _examples_X(st, sp.lower)])
    )
    m["ground_speed_m_per_s"] = M.ground_speed(r, sk.rate)
    step = jax.jit(M.synthesize_step)
    s0 = M.init_state(sp, qL[0])
    s0 = s0._replace(t_lower=jnp.asarray(5.0, s0.t_lower.dtype), t_upper=sp.lam[5])
    reps = sy.timing_repeats
    m["step_ms"] = 1e3 * _timeit(step, sp, s0, up0, qL[0], sy.alpha, 1.0, repeats=reps)
    m["step_with_replacement_ms"] = 1e3 * _timeit(
        step, sp, s0, up0, qL[1], sy.alpha, 1.0, repeats=reps
    )
    if parametric:
        exact_f = jax.jit(lambda w: M.exact_upper_params(sp, w))
        m["exact_resample_ms"] = 1e3 * _timeit(exact_f, knnL(qL[1]), repeats=reps)
    return m, {"X": X, "clocks": clocks, "up0": up0}
