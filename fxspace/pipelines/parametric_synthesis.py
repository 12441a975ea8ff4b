"""Decoupled upper/lower-body parametric motion synthesis (Ha & Han), the three set-ups of
the paper's Table 1 on real captures (see `fxspace.motion._setups`):

- ``mood_walk`` (Bandai Namco): joy/sad upper body set by weight, direction walks below;
- ``block_walk`` (Bandai Namco): left-hand position above, direction walks below;
- ``block_kick`` (CMU subject 135): left-hand blocks above, right-foot kicks below,
  3-key-time alignment.

Per set-up this wiring builds the spaces (`fxspace.motion.prepare_setup`), measures
target-reaching errors with and without the §3.2 re-placement and against re-sampling from
scratch, synthesises clips with `fxspace.motion.synthesize` (fixed parameters, and a
lower parameter steered during the clip), times one `fxspace.motion.synthesize_step`
with and without re-placement, reports foot sliding, and for the mood walk sweeps the joy
weight (speed figure). Writes ``<setup>.bvh``, ``<setup>_steer.bvh``, figures and metrics.

One's own clips: ``[data] source = "files"`` and ``[[data.clips]]`` entries (``path`` to a
BVH or AMC file, ``part = "lower"`` / ``"upper"``, ``label``; see
`fxspace.motion.SetupClip`), BVH ``units`` declared or inferred from the leg length (said
on the console), joints found by role (`fxspace.motion.joint_map_for`; ``[skeleton] map``
names the ones no naming convention covers). Every clip read is listed, with its units and
frames, in the set-up's ``clips`` metric.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace._progress import progress
from fxspace.config import ConfigError
from fxspace.pipelines._planner import _data_files, resolve_config

# the experiment's parts, one job each: its config (`_synthesis_config`), its clips
# (`_synthesis_clips`), a set-up stored as arrays (`_synthesis_store`), the measured stages
# (`_synthesis_stages`) and Fig. 3 / α's cadence (`_synthesis_fig3`); its figures are drawn
# by `fxspace.plot` and saved here
from fxspace.pipelines._synthesis_clips import (
    _build_setup,
    data_files,
    load_take,
    read_clip,
    take_files,
)
from fxspace.pipelines._synthesis_config import Config
from fxspace.pipelines._synthesis_config import SynthConfig as SynthConfig
from fxspace.pipelines._synthesis_fig3 import _fig3_metrics_of, _fig3_panels, _fig3_sessions
from fxspace.pipelines._synthesis_fig3 import _gait_joints as _gait_joints
from fxspace.pipelines._synthesis_fig3 import alpha_cadence as alpha_cadence
from fxspace.pipelines._synthesis_fig3 import fig3_metrics as fig3_metrics
from fxspace.pipelines._synthesis_stages import (
    _clip,
    _clips_and_timing,
    _queries,
    _stage_session,
    _stage_targets,
    _stage_timewarp,
)
from fxspace.pipelines._synthesis_store import _setup_from_arrays, _stage_setup
from fxspace.pipelines._synthesis_store import _setup_to_arrays as _setup_to_arrays
from fxspace.runs import cached, run_key, save_figure_atomic, write_json_atomic

STAGES: tuple[str, ...] = ("setup", "targets", "timewarp", "session")
APP = "fxspace.studio._motion:serve"  # `fxspace studio` of a run: the motion app
REPRODUCTION = "ha-han"  # its reproduction page (`fxspace docs`)

__all__ = [
    "Config",
    "STAGES",
    "prepare_app",
    "run",
    "load_take",
    "read_clip",
    "take_files",
    "data_files",
    "load_setup",
    "scripted_session",
    "session_parameters",
]


_SETUPS: dict = {}


def load_setup(config: str | Path, setup: str | None = None) -> M.Setup:
    """The built set-up of a ``parametric_synthesis`` config file (or a run folder holding
    ``config.toml``), the same spaces `run` builds; ``setup`` picks one of its ``setups``
    (default the first). Kept in memory per file and modification time.

    A finished run folder's stored ``setup`` stage is read instead of rebuilt when the
    folder's cache is bound to this config, data and code (its ``cache/KEY`` equals the
    run key `fxspace run` would compute now): the studio opens in seconds, never on
    another config's spaces."""
    p = Path(config)
    cfg_p = p / "config.toml" if p.is_dir() else p
    spec = resolve_config(config, experiment="parametric_synthesis")[0]  # a sweep: its first
    cfg, seed = spec.config, spec.seed
    name = setup or cfg.setups[0]
    if name not in cfg.setups:
        raise ConfigError(f"setup {name!r} is not among the config's setups {list(cfg.setups)}")
    ck = (str(cfg_p.resolve()), cfg_p.stat().st_mtime_ns, name)
    if ck not in _SETUPS and p.is_dir():
        stored = _stored_setup(p, name, cfg)
        if stored is not None:
            _SETUPS[ck] = stored
    if ck not in _SETUPS:
        key = jax.random.fold_in(
            jax.random.fold_in(jax.random.PRNGKey(seed), cfg.setups.index(name)), 0
        )
        _SETUPS[ck] = _build_setup(name, cfg, key)
    return _SETUPS[ck]


def scripted_session(
    config: str | Path,
    schedule,
    seconds: float,
    *,
    setup: str | None = None,
    smoothing_s: float = 0.3,
) -> tuple[np.ndarray, float, list[str]]:
    """Run the live controller of a ``parametric_synthesis`` config without a browser
    (continuous locomotion, `fxspace.motion.run_session`).

    **Arguments:** ``config`` a TOML path (or run folder); ``schedule`` a list of
    ``(time_s, {parameter: value})`` with the names of `session_parameters`; ``seconds``
    the session's length.

    **Returns:** ``(positions, fps, names)``: world joint positions ``(frames, joints, 3)``
    in metres, y up; the frame rate; the joint names.
    """
    X, fps, names, _ = M.run_session(load_setup(config, setup), schedule, seconds, smoothing_s)
    return X, fps, names


def session_parameters(
    config: str | Path, *, setup: str | None = None
) -> dict[str, tuple[float, float]]:
    """The controllable parameters of a config's set-up, ``{name: (low, high)}``: ``alpha``,
    ``turn`` (°/s, walks), ``joy`` (mood walk), ``hand_x/y/z`` (root frame) or
    ``foot_x/y/z`` (see `fxspace.motion.session_controls`)."""
    return M.session_controls(load_setup(config, setup))


_TABLE1 = {  # Ha & Han, Table 1: example counts (upper, lower)
    "mood_walk": (2, 10),
    "block_walk": (12, 12),
    "block_kick": (12, 11),
}
_TABLE1_WHY = {
    "mood_walk": "Bandai Namco: joy/sad walks (upper); 2 straight + 4 turn-left + 4 turn-right "
    "walks (lower), as in the paper's 10 direction walks",
    "block_walk": "Bandai Namco: 12 raise-left-hand takes (upper), 4 straight + 4 turn-left + "
    "4 turn-right walks (lower)",
    "block_kick": "CMU subject 135: left-hand blocks cut from takes 05/10/09 (up to data.max_reps "
    "each) and right-foot kicks from takes 04/07/11; the takes hold fewer clean right kicks "
    "than the paper's 11 (each detected kick apex is used once)",
}



def _stored_setup(run_dir: Path, name: str, cfg: Config) -> M.Setup | None:
    """``run_dir``'s stored ``setup`` stage if its cache is bound to the folder's own config,
    data and code (``cache/KEY`` = the run key computed now), else None."""
    kp, sp = run_dir / "cache" / "KEY", run_dir / "cache" / f"{name}_setup.npz"
    if not (kp.is_file() and sp.is_file()):
        return None
    text = (run_dir / "config.toml").read_text()
    try:
        key = run_key(text, _data_files(sys.modules[__name__], cfg))
    except OSError:  # a clip is missing (DataNotFoundError): the rebuild names it
        return None
    if kp.read_text().strip() != key:
        return None
    try:
        with open(sp, "rb") as f, np.load(f, allow_pickle=False) as z:  # f closed if torn
            return _setup_from_arrays({k: z[k] for k in z.files})
    except Exception as e:  # noqa: BLE001 - BadZipFile (torn), zlib.error, EOFError, KeyError...
        print(f"[fxspace] {sp} is damaged ({type(e).__name__}); rebuilding the {name} set-up")
        return None



def _figures(st: M.Setup, cfg: Config, run_dir: Path, qL, extra: dict, curves: dict) -> None:
    from fxspace import plot as P

    sp, name, sy = st.spaces, st.name, cfg.synth
    EL = sp.lower.warps.shape[0]
    knn = jax.vmap(
        lambda p: M.knn_blend_weights(p, sp.lower_params, sp.lower_weights, sp.knn_k).weights
    )
    achL = jax.jit(jax.vmap(lambda w: M.lower_param_of(sp, w)))(knn(qL))
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
    if sp.upper_joint >= 0:
        wL1 = knn(qL[1:2])[0]
        save_figure_atomic(
            P.plot_replacement(
                sp.upper_params,
                M.replace_samples(sp, wL1),
                M.exact_upper_params(sp, wL1),
                title=f"{name}: upper samples, re-placed (k={sp.k_replace}) vs exact",
            ),
            run_dir / f"{name}_replacement.png",
        )
    save_figure_atomic(
        P.plot_filmstrip(
            extra["X"], st.skeleton.parents, n_panels=8, title=f"{name} (α={sy.alpha})"
        ),
        run_dir / f"{name}_filmstrip.png",
    )
    save_figure_atomic(
        P.plot_clocks(
            {a: extra["clocks"][a] for a in sy.alphas},
            np.asarray(sp.lam),
            title=f"{name}: clocks T_L (--), T_U (—)",
        ),
        run_dir / f"{name}_clocks.png",
    )
    t = np.arange(len(next(iter(curves["warped"].values()))))
    save_figure_atomic(
        P.plot_timewarp(
            t,
            curves["warped"],
            curves["plain"],
            curves["examples"],
            title=f"{name}: eq. 1 registration, blends with and without time-warp",
        ),
        run_dir / f"{name}_registration_timewarp.png",
    )
    if extra.get("fig3"):
        phases, swings = _fig3_panels(st, extra["fig3"])
        title = f"{name}: Fig. 3 read off the joints (arm swing against the strides)"
        save_figure_atomic(P.plot_arm_swing_coupling(phases, swings, title=title),
                           run_dir / f"{name}_fig3.png")  # fmt: skip


def _joy_sweep(st: M.Setup, cfg: Config, run_dir: Path, qL) -> dict:
    """The paper's observation for the mood walk: joy weight ↑ → the whole walk faster."""
    from fxspace import plot as P

    sp, sy, rate = st.spaces, cfg.synth, st.skeleton.rate
    n_ref = int(sp.lam.shape[0])
    speeds = {
        a: [
            M.ground_speed(_clip(sp, jnp.asarray([j, 1 - j]), qL[0], a, n_ref)[1], rate)
            for j in sy.joy_weights
        ]
        for a in progress(sy.alphas, f"{st.name}: joy sweep")
    }
    labels = st.info.get("upper_labels") or ["joy", "sad"]
    axis = st.info.get("upper_axis") or f"{labels[0]} weight ({labels[1]} = 1 − {labels[0]})"
    save_figure_atomic(
        P.plot_speed_vs_weight(
            sy.joy_weights, speeds, title=f"{st.name}: speed vs {labels[0]} weight", xlabel=axis
        ),
        run_dir / f"{st.name}_speed_vs_joy.png",
    )
    return {  # "joy": the weight of the first upper clip, whatever its label (upper_axis)
        "speed_vs_joy": {f"alpha={a:g}": v for a, v in speeds.items()},
        "joy_weights": list(sy.joy_weights),
        "upper_axis": axis,
        "upper_labels": list(labels),
    }


def prepare_app(cfg: Config, run_dir: Path, seed: int) -> None:
    """What the live controller shows, and only that (``fxspace studio CONFIG``): the
    first set-up's spaces (the run's own ``setup`` stage, reused by ``fxspace run``)."""
    cfg.validate()
    with jax.enable_x64(cfg.x64):
        key = jax.random.fold_in(jax.random.PRNGKey(seed), 0)  # as `run` keys set-up 0
        _stage_setup(cfg.setups[0], cfg, Path(run_dir), key)


def _run_setup(name: str, cfg: Config, run_dir: Path, key, seed: int) -> dict:
    st = _stage_setup(name, cfg, run_dir, key)  # stage "setup"
    qL, wq_u = _queries(st, cfg, key)
    m: dict = {**st.info, "n_samples": int(st.spaces.lower_weights.shape[0])}
    m["preprocessing_s"] = st.info["registration_s"] + st.info["sampling_s"]
    paper = _TABLE1[name]
    m["table1"] = {
        "paper_upper_lower": list(paper),
        "ours_upper_lower": [st.info["n_upper_examples"], st.info["n_lower_examples"]],
        "clips": _TABLE1_WHY[name] if cfg.data.source != "files" else (
            f"one's own clips: lower {st.info['lower_labels']}, upper {st.info['upper_labels']}"
        ),
    }
    m.update(cached(run_dir, f"{name}_targets", lambda: _stage_targets(st, cfg, qL, wq_u)))
    tw = {}

    def timewarp() -> dict:
        met, curves = _stage_timewarp(st)
        tw["curves"] = curves
        return {
            **met,
            "curves": {
                k: {c: np.asarray(v).tolist() for c, v in d.items()} for k, d in curves.items()
            },
        }

    reg = cached(run_dir, f"{name}_timewarp", timewarp)
    curves = reg.pop("curves")
    m.update(reg)
    f3 = _fig3_sessions(st, cfg, seed)
    m.update(_fig3_metrics_of(f3))
    if name != "block_kick" and cfg.synth.session_s > 0:
        m.update(cached(run_dir, f"{name}_session", lambda: _stage_session(st, cfg, seed, run_dir)))
    more, extra = _clips_and_timing(st, cfg, run_dir, qL, wq_u)
    extra["fig3"] = f3
    m.update(more)
    _figures(st, cfg, run_dir, qL, extra, curves)
    if st.spaces.upper_joint < 0:
        m.update(_joy_sweep(st, cfg, run_dir, qL))
    return m


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the configured set-ups; returns ``{setup: metrics}`` and writes per-set-up files.
    Stages (`STAGES`, cached per set-up in ``run_dir/cache``: an interrupted run resumes):
    ``setup`` (registration + sampling), ``targets``, ``timewarp`` (Fig. 3), ``session``."""
    with jax.enable_x64(cfg.x64):
        key = jax.random.PRNGKey(seed)
        metrics: dict = {}
        for i, name in enumerate(cfg.setups):
            metrics[name] = _run_setup(name, cfg, Path(run_dir), jax.random.fold_in(key, i), seed)
            write_json_atomic(Path(run_dir) / f"{name}_metrics.json", metrics[name])
            print(
                f"[parametric_synthesis] {name}: "
                + ", ".join(
                    f"{k}={v:.4g}" for k, v in metrics[name].items() if isinstance(v, float)
                )
            )
        return metrics
