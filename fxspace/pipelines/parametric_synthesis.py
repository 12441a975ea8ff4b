"""Decoupled upper/lower-body parametric motion synthesis (Ha & Han), the three set-ups of
the paper's Table 1 on real captures (see :mod:`fxspace.motion._setups`):

- ``mood_walk`` (Bandai Namco): joy/sad upper body set by weight, direction walks below;
- ``block_walk`` (Bandai Namco): left-hand position above, direction walks below;
- ``block_kick`` (CMU subject 135): left-hand blocks above, right-foot kicks below,
  3-key-time alignment.

Per set-up this wiring builds the spaces (:func:`fxspace.motion.prepare_setup`), measures
target-reaching errors with and without the §3.2 re-placement and against re-sampling from
scratch, synthesises clips with :func:`fxspace.motion.synthesize` (fixed parameters, and a
lower parameter steered during the clip), times one :func:`fxspace.motion.synthesize_step`
with and without re-placement, reports foot sliding, and for the mood walk sweeps the joy
weight (speed figure). Writes ``<setup>.bvh``, ``<setup>_steer.bvh``, figures and metrics.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace._progress import progress
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.io import Motion, read_amc, read_bvh, write_bvh
from fxspace.runs import save_figure_atomic, write_json_atomic

__all__ = ["Config", "run", "load_take"]


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    alphas: tuple[float, ...] = (0.0, 0.5, 1.0)
    alpha: float = 0.5  # the one written as BVH
    n_queries: int = 20
    joy_weights: tuple[float, ...] = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)
    timing_repeats: int = 20


@dataclasses.dataclass(frozen=True)
class Config:
    setups: tuple[str, ...] = ("mood_walk", "block_walk", "block_kick")
    stride: int = 4  # CMU 120 Hz → 30 Hz (the Bandai clips are 30 Hz)
    data: M.SetupData = M.SetupData()
    space: M.SetupSpace = M.SetupSpace()
    synth: SynthConfig = SynthConfig()

    def validate(self) -> None:
        for s in self.setups:
            if s not in M.SETUPS:
                raise ConfigError(f"setups: unknown set-up {s!r}; choose from {list(M.SETUPS)}")
        if self.stride < 1:
            raise ConfigError("stride must be >= 1")
        if not 0.0 <= self.synth.alpha <= 1.0 or any(not 0 <= a <= 1 for a in self.synth.alphas):
            raise ConfigError("synth.alpha and synth.alphas must lie in [0, 1]")
        if not 3 <= self.space.k_replace <= self.space.n_samples:
            raise ConfigError("space.k_replace must be between 3 and space.n_samples")
        if self.space.knn_k < 2:
            raise ConfigError("space.knn_k must be at least 2 (k-NN interpolation)")
        if self.synth.n_queries < 2:
            raise ConfigError("synth.n_queries must be at least 2")


def load_take(take: str, stride: int = 4) -> Motion:
    """A clip by take name: Bandai Namco ``dataset-…`` (BVH, cm, static root dropped) or CMU
    ``SSS_TT`` (ASF/AMC, every ``stride``-th frame)."""
    if take.startswith("dataset-"):
        m = read_bvh(data_path("body", "bandai", f"{take}.bvh.gz"), scale=0.01)
        return M.drop_root(m)
    subj = take.split("_")[0]
    m = read_amc(
        data_path("body", "cmu", subj, f"{subj}.asf"),
        data_path("body", "cmu", subj, f"{take}.amc.gz"),
    )
    return m.frames(slice(None, None, stride))


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


def _run_setup(name: str, cfg: Config, run_dir: Path, key) -> dict:
    from fxspace import plot as P

    sy = cfg.synth
    setup = M.prepare_setup(
        name, lambda t: load_take(t, cfg.stride), cfg.data, cfg.space, jax.random.fold_in(key, 0)
    )
    sp, skel = setup.spaces, setup.skeleton
    parametric = sp.upper_joint >= 0
    n_ref = int(sp.lam.shape[0])
    EL, EU = sp.lower.warps.shape[0], sp.upper.warps.shape[0]
    # queries: parameters of fresh random blends (inside the spaces)
    kq1, kq2 = jax.random.split(jax.random.fold_in(key, 1))
    nq = sy.n_queries
    wq_l = M.sample_blend_weights(kq1, EL, EL + nq, cfg.space.concentration)[EL:]
    wq_u = M.sample_blend_weights(kq2, EU, EU + nq, cfg.space.concentration)[EU:]
    lower_of = jax.jit(jax.vmap(lambda w: M.lower_param_of(sp, w)))
    knnL = jax.jit(
        lambda p: M.knn_blend_weights(p, sp.lower_params, sp.lower_weights, sp.knn_k).weights
    )
    qL = lower_of(wq_l)
    err_l = []
    rows = []
    exact_f = jax.jit(lambda w: M.exact_upper_params(sp, w))
    replace_f = jax.jit(lambda w: M.replace_samples(sp, w))

    @jax.jit
    def reach(wL, pU, params):
        wU = M.knn_blend_weights(pU, params, sp.upper_weights, sp.knn_k).weights
        return jnp.linalg.norm(M.upper_param_of(sp, wL, wU) - pU)

    for i in progress(range(nq), f"{name}: targets", total=nq):
        wL = knnL(qL[i])
        err_l.append(float(np.linalg.norm(np.asarray(M.lower_param_of(sp, wL) - qL[i]))))
        if parametric:
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
                ]
            )
    m: dict = {**setup.info, "n_samples": int(sp.lower_weights.shape[0])}
    m["preprocessing_s"] = setup.info["registration_s"] + setup.info["sampling_s"]
    m["lower_target_error_mean_m"] = float(np.mean(err_l))
    m["lower_target_error_max_m"] = float(np.max(err_l))
    if parametric:
        r = np.asarray(rows)
        m.update(
            k_replace=sp.k_replace,
            upper_target_error_replaced_mean_m=float(r[:, 0].mean()),
            upper_target_error_stale_mean_m=float(r[:, 1].mean()),
            upper_target_error_resampled_mean_m=float(r[:, 2].mean()),
            replacement_error_mean_m=float(r[:, 3].mean()),
            replacement_error_max_m=float(r[:, 4].max()),
            stale_sample_error_mean_m=float(r[:, 5].mean()),
        )

    # synthesis: fixed parameters, then a lower parameter steered through the clip
    up0 = M.upper_param_of(sp, knnL(qL[0]), wq_u[0]) if parametric else jnp.asarray([0.5, 0.5])
    clocks, outs = {}, {}
    for a in sy.alphas + (sy.alpha,):
        q, r, c = _clip(sp, up0, qL[0], a, n_ref)
        clocks[a], outs[a] = (c[:, 0], c[:, 1]), (q, r)
    m["clocks_monotone_all_alphas"] = bool(
        all(np.all(np.diff(u) >= -1e-9) and np.all(np.diff(v) >= -1e-9) for u, v in clocks.values())
    )
    q, r = outs[sy.alpha]
    write_bvh(
        run_dir / f"{name}.bvh",
        dataclasses.replace(skel, root_translation=r, rotations=q),
        scale=setup.scale,
    )
    X = np.asarray(M.fk_arrays(skel.parents, np.asarray(skel.offsets), r, q)[0])
    s = np.linspace(0.0, 1.0, 3 * n_ref)[:, None]
    steer = (1 - s) * np.asarray(qL[0]) + s * np.asarray(qL[1])
    qs, rs, _ = _clip(sp, up0, jnp.asarray(steer), sy.alpha, n_ref)
    write_bvh(
        run_dir / f"{name}_steer.bvh",
        dataclasses.replace(skel, root_translation=rs, rotations=qs),
        scale=setup.scale,
    )
    m["frames_synthesised"] = int(q.shape[0])
    m["foot_sliding_m_per_s"] = M.foot_sliding(X, setup.feet, skel.rate)
    ex_slide = []
    for i in range(EL):
        n_i = int(sp.lower.lengths[i])
        Xi = M.fk_arrays(
            skel.parents,
            np.asarray(skel.offsets),
            np.asarray(sp.lower.root[i, :n_i]),
            np.asarray(sp.lower.rotations[i, :n_i]),
        )[0]
        ex_slide.append(M.foot_sliding(Xi, setup.feet, skel.rate))
    m["foot_sliding_examples_m_per_s"] = float(np.nanmean(ex_slide))
    m["ground_speed_m_per_s"] = M.ground_speed(r, skel.rate)

    # one step, with and without re-placement (the lower parameter alternates / stays)
    step = jax.jit(M.synthesize_step)
    st = M.init_state(sp, qL[0])
    st = st._replace(t_lower=jnp.asarray(5.0, st.t_lower.dtype), t_upper=sp.lam[5])
    m["step_ms"] = 1e3 * _timeit(step, sp, st, up0, qL[0], sy.alpha, 1.0, repeats=sy.timing_repeats)
    m["step_with_replacement_ms"] = 1e3 * _timeit(
        step, sp, st, up0, qL[1], sy.alpha, 1.0, repeats=sy.timing_repeats
    )
    if parametric:
        m["exact_resample_ms"] = 1e3 * _timeit(exact_f, knnL(qL[1]), repeats=sy.timing_repeats)

    # figures
    achL = lower_of(jax.vmap(knnL)(qL))
    save_figure_atomic(
        P.plot_parameter_space(
            np.asarray(sp.lower_params),
            np.asarray(sp.lower_params[:EL]),
            np.asarray(qL),
            np.asarray(achL),
            title=f"{name}: lower-body space",
        ),
        run_dir / f"{name}_lower_space.png",
    )
    if parametric:
        wL1 = knnL(qL[1])
        save_figure_atomic(
            P.plot_replacement(
                sp.upper_params,
                replace_f(wL1),
                exact_f(wL1),
                title=f"{name}: upper samples, re-placed (k={sp.k_replace}) vs exact",
            ),
            run_dir / f"{name}_replacement.png",
        )
    save_figure_atomic(
        P.plot_filmstrip(X, skel.parents, n_panels=8, title=f"{name} (α={sy.alpha})"),
        run_dir / f"{name}_filmstrip.png",
    )
    save_figure_atomic(
        P.plot_clocks(
            {a: clocks[a] for a in sy.alphas},
            np.asarray(sp.lam),
            title=f"{name}: clocks T_L (--), T_U (—)",
        ),
        run_dir / f"{name}_clocks.png",
    )
    if not parametric:  # the paper's observation: joy weight ↑ → the whole walk faster
        speeds: dict = {}
        for a in progress(sy.alphas, f"{name}: joy sweep"):
            speeds[a] = [
                M.ground_speed(_clip(sp, jnp.asarray([j, 1 - j]), qL[0], a, n_ref)[1], skel.rate)
                for j in sy.joy_weights
            ]
        m["speed_vs_joy"] = {f"alpha={a:g}": v for a, v in speeds.items()}
        m["joy_weights"] = list(sy.joy_weights)
        save_figure_atomic(
            P.plot_speed_vs_weight(sy.joy_weights, speeds, title=f"{name}: speed vs joy weight"),
            run_dir / f"{name}_speed_vs_joy.png",
        )
    return m


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the configured set-ups; returns ``{setup: metrics}`` and writes per-set-up files."""
    key = jax.random.PRNGKey(seed)
    metrics: dict = {}
    for i, name in enumerate(cfg.setups):
        metrics[name] = _run_setup(name, cfg, Path(run_dir), jax.random.fold_in(key, i))
        write_json_atomic(Path(run_dir) / f"{name}_metrics.json", metrics[name])
        print(
            f"[parametric_synthesis] {name}: "
            + ", ".join(f"{k}={v:.4g}" for k, v in metrics[name].items() if isinstance(v, float))
        )
    return metrics
