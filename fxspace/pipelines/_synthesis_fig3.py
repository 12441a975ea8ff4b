"""Ha & Han Fig. 3 read off the synthesised joints (`fig3_metrics`: the arm swing against
the strides, clocks apart and aligned) and issue 47's check that α is alive
(`alpha_cadence`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.pipelines._synthesis_clips import load_take
from fxspace.pipelines._synthesis_config import Config
from fxspace.pipelines._synthesis_stages import _examples_X, _schedule

#: (left, right) joint names of the feet, hands and hips, per skeleton convention
_GAIT_JOINTS = (
    (("Toes_L", "Toes_R"), ("Hand_L", "Hand_R"), ("UpperLeg_L", "UpperLeg_R")),  # Bandai
    (("ltoes", "rtoes"), ("lhand", "rhand"), ("lfemur", "rfemur")),  # CMU ASF
)


def _gait_joints(skel) -> tuple | None:
    """``(feet, hands, hips)`` index pairs of a skeleton (None: names not found)."""
    names = list(skel.names)
    for conv in _GAIT_JOINTS:
        if all(n in names for pair in conv for n in pair):
            return tuple(tuple(names.index(n) for n in pair) for pair in conv)
    return None


def _walks(st: M.Setup) -> bool:
    return st.name in ("mood_walk", "block_walk")


_FIG3_KINDS = {  # metric suffix: how the clocks run
    "unaligned": dict(aligned=False),  # (a): eq. 1 only, each half on its own clock
    "aligned_as_printed": dict(max_clock_rate=float("inf")),  # (b): eqs. 2–3 as printed
    "aligned": {},  # (b): eqs. 2–3 with the default bound (`clock_bounds`)
}


def _fig3_sessions(st: M.Setup, cfg: Config, seed: int) -> dict:
    """Ha & Han Fig. 3 read off the synthesised joints: one long scripted session of a
    walk (``synth.session_s``, 60 s when 0; every control but α changed every
    ``synth.session_every_s``, α = ``synth.alpha``) played (a) with each body half on its
    own clock and (b) aligned by eqs. 2–3, as printed and with the default bound; on each,
    the upper body's arm swing against the strides read off the feet
    (`fxspace.motion.cycle_coupling`), and the same on the captured takes."""
    joints = _gait_joints(st.skeleton)
    if not _walks(st) or joints is None:
        return {}
    feet, hands, hips = joints
    sy = cfg.synth
    seconds = sy.session_s if sy.session_s > 0 else 60.0
    table = M.session_turn_table(st)
    controls = M.session_controls(st, table)
    sched = [(t, {**c, "alpha": sy.alpha}) for t, c in
             _schedule(controls, seconds, sy.session_every_s, seed)]  # fmt: skip
    out: dict = {}
    for kind, change in _FIG3_KINDS.items():
        st2 = st._replace(spaces=dataclasses.replace(st.spaces, **change))
        X, fps, _, _ = M.run_session(st2, sched, seconds, table=table)
        out[kind] = (M.cycle_coupling(X, feet, hands, hips, fps), X)
    ex = []
    for take in st.upper_names + st.lower_names:
        mot = load_take(take, cfg.stride)
        Xe = np.asarray(M.fk_arrays(mot.parents, mot.offsets, mot.root_translation,
                                    mot.rotations)[0])  # fmt: skip
        ex.append(M.cycle_coupling(Xe, feet, hands, hips, mot.rate))
    out["examples"] = ex
    return out


def _fig3_metrics_of(f3: dict) -> dict:
    if not f3:
        nan = float("nan")
        return {f"fig3_{m}_{k}": nan for m in ("phase_drift", "cycle_ratio")
                for k in (*_FIG3_KINDS, "examples")}  # fmt: skip
    m: dict = {}
    for k in _FIG3_KINDS:
        c = f3[k][0]
        m[f"fig3_phase_drift_{k}"] = c.phase_drift
        m[f"fig3_cycle_ratio_{k}"] = c.cycle_ratio
    ex = f3["examples"]
    m["fig3_phase_drift_examples"] = float(np.nanmean([c.phase_drift for c in ex]))
    m["fig3_cycle_ratio_examples"] = float(np.nanmean([c.cycle_ratio for c in ex]))
    m["fig3_phase_drift_examples_max"] = float(np.nanmax([c.phase_drift for c in ex]))
    m["fig3_units"] = (
        "read off the joints: cycle_ratio = mean arm-swing cycle / mean stride (left foot "
        "against right); phase_drift = how fast the arm swing's phase at each stride slips, "
        "cycles per minute; examples = the captured takes (mean)"
    )
    return m



def _fig3_panels(st: M.Setup, f3: dict) -> tuple[list, list]:
    """What `fxspace.plot.plot_arm_swing_coupling` draws of `_fig3_sessions`' ``f3``:
    ``(phases, swings)``, the couplings of the three ways the clocks ran, and the forward
    offsets of the feet and of the hands over the first 8 s, clocks apart and aligned."""
    kinds = (("unaligned", "(a) clocks apart"),
             ("aligned_as_printed", "(b) eqs. 2–3 as printed"),
             ("aligned", "(b) eqs. 2–3, bounded (default)"))  # fmt: skip
    phases = [(lab, f3[k][0]) for k, lab in kinds]
    feet, hands, hips = _gait_joints(st.skeleton)
    rate = float(st.skeleton.rate)
    swings = []
    for k in ("unaligned", "aligned"):
        X = f3[k][1][: int(8 * rate)]
        t = np.arange(X.shape[0]) / rate
        swings.append(("(a) clocks apart" if k == "unaligned" else "(b) aligned", t,
                       M.swing_signal(X, feet[0], feet[1], hips),
                       M.swing_signal(X, hands[1], hands[0], hips)))  # fmt: skip
    return phases, swings


def fig3_metrics(st: M.Setup, cfg: Config, seed: int = 0) -> dict:
    """Ha & Han Fig. 3 measured on the synthesised joints (`_fig3_sessions`):
    ``fig3_phase_drift_{unaligned,aligned_as_printed,aligned,examples}`` (cycles per
    minute the arm swing's phase slips against the strides) and ``fig3_cycle_ratio_*``
    (mean arm-swing cycle / mean stride); NaN for a set-up that is not a walk."""
    return _fig3_metrics_of(_fig3_sessions(st, cfg, seed))


def alpha_cadence(st: M.Setup, cfg: Config, seeds=range(5), seconds: float = 60.0) -> dict:
    """Issue 47's check that α is alive under the default bound: per scripted session
    (``seeds``: random turns — and hand positions — every ``synth.session_every_s``; joy
    held at 1 on the mood walk), the lower body's cadence read off the feet
    (`fxspace.motion.cadence`, strides per second) at α = 0 and at α = 1, beside what
    eqs. 1–3 predict from the clocks alone (`fxspace.motion.clock_cycle_rate` per
    control segment, blends held; with the bound, and as printed) and what the walker's
    own clocks do with each segment's controls held (``predicted_walker_*``: the
    clock-rate bound plus the joint-speed guard, which reads the poses); and each joint's
    fastest speed against the fastest captured clip's same joint (body heights per
    second, `fxspace.motion.joint_speeds`)."""
    sp, sk = st.spaces, st.skeleton
    feet, _, hips = _gait_joints(sk)
    fps = float(sk.rate)
    table = M.session_turn_table(st)
    controls = M.session_controls(st, table)
    names = list(controls)
    Xe = _examples_X(st, sp.lower) + _examples_X(st, sp.upper)
    height = float(np.ptp(Xe[0][0, :, 1]))
    ex_speed = np.max([M.joint_speeds(x, fps, height) for x in Xe], axis=0)
    free = dataclasses.replace(sp, max_clock_rate=float("inf"))
    knnL = jax.jit(lambda p: M.knn_blend_weights(p, sp.lower_params, sp.lower_weights,
                                                 sp.knn_k).weights)  # fmt: skip
    rows = []
    for seed in seeds:
        sched = _schedule(controls, seconds, cfg.synth.session_every_s, 1000 + seed)
        if "joy" in controls:
            sched = [(t, {**c, "joy": 1.0}) for t, c in sched]
        row: dict = {"seed": int(seed)}
        for a in (0.0, 1.0):
            s_a = [(t, {**c, "alpha": a}) for t, c in sched]
            X, _, _, _ = M.run_session(st, s_a, seconds, table=table)
            row[f"cadence_alpha{a:g}"] = M.cadence(X, feet, hips, fps)
            row[f"joint_speed_ratio_alpha{a:g}"] = float(
                np.max(M.joint_speeds(X, fps, height) / ex_speed))
            pred, pred_free, seg_up, seg_low = [], [], [], []
            for _t, c in sched:  # per control segment, blends held (no smoothing)
                v = np.asarray([[{**c, "alpha": a}[n] for n in names]], np.float64)
                up, low, _ = M.controls_to_params(st, names, v, table)
                wL = knnL(jnp.asarray(low[0], sp.lam.dtype))
                if sp.upper_joint >= 0:
                    params = M.replace_samples(sp, wL)
                    wU = M.knn_blend_weights(jnp.asarray(up[0], sp.lam.dtype), params,
                                             sp.upper_weights, sp.knn_k).weights  # fmt: skip
                else:
                    wU = jnp.asarray(up[0] / up[0].sum(), sp.lam.dtype)
                pred.append(float(M.clock_cycle_rate(sp, wL, wU, a)))
                pred_free.append(float(M.clock_cycle_rate(free, wL, wU, a)))
                seg_up.append(up[0])
                seg_low.append(low[0])
            row[f"predicted_alpha{a:g}"] = float(np.mean(pred)) * fps
            starts = np.asarray([t for t, _ in sched], np.float64)
            seg = np.searchsorted(starts, np.arange(int(round(seconds * fps))) / fps, "right") - 1
            row[f"predicted_walker_alpha{a:g}"] = fps * _held_walk_rate(
                sp, np.asarray(seg_up)[seg], np.asarray(seg_low)[seg], a
            )
            row[f"predicted_as_printed_alpha{a:g}"] = float(np.mean(pred_free)) * fps
        row["ratio_measured"] = row["cadence_alpha0"] / row["cadence_alpha1"]
        row["ratio_predicted"] = row["predicted_alpha0"] / row["predicted_alpha1"]
        row["ratio_predicted_as_printed"] = (row["predicted_as_printed_alpha0"]
                                             / row["predicted_as_printed_alpha1"])  # fmt: skip
        row["ratio_predicted_walker"] = (row["predicted_walker_alpha0"]
                                         / row["predicted_walker_alpha1"])  # fmt: skip
        rows.append(row)
    return {"sessions": rows, "examples_joint_speed_max_bh_per_s": ex_speed.tolist(),
            "body_height_m": height}  # fmt: skip


def _held_walk_rate(sp, ups, lows, alpha: float) -> float:
    """Lower reference cycles per output frame of the walker's own clocks
    (`fxspace.motion.locomotion` over ``(F, ·)`` parameters, each control segment's held
    without the session's lags): `clock_cycle_rate`'s eqs. 1–3 with the clock-rate bound,
    plus the joint-speed guard, which needs the poses."""
    dtype = sp.lam.dtype
    ups, lows = jnp.asarray(ups, dtype), jnp.asarray(lows, dtype)
    F = ups.shape[0]
    final, _ = M.locomotion(sp, M.init_locomotion(sp, lows[0]), ups, lows,
                            jnp.full((F,), alpha, dtype))  # fmt: skip
    return (float(final.cycles) + float(final.synth.t_lower) / (sp.lam.shape[0] - 1.0)) / F
