"""Decoupled upper/lower-body parametric motion synthesis (Ha & Han) on CMU clips.

Two set-ups after the paper's Table 1, with the clips we have:

- ``walk_block``: lower space = walks of subject 131 (start/walk/stop, left, right),
  parameter = where the left foot ends (x, z); DTW registration to a reference walk.
  Upper space = left-hand actions of subject 135 (downward block, knife-hand block, lunge
  punch; each repetition one example), parameter = left-hand position at the key time
  (relative to the pelvis); key-time registration. λ between the two reference clips by
  DTW on their lower bodies.
- ``kick_block``: lower space = right-foot kicks of subject 135 (front, roundhouse, side;
  each repetition one example), parameter = right-toe position at the apex; key-time
  registration (lift-off, apex, landing). Same upper space; λ from key times.

Each set-up: samples ``n_samples`` random blends per space, answers parameter queries
by k-NN interpolation, synthesises frames with the two synchronised clocks and the
splice, and measures parameter error, foot sliding, time per frame, preprocessing time
and the Horn re-placement error. Writes ``<setup>.bvh``, figures and metrics.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.io import Motion, read_amc, write_bvh
from fxspace.runs import save_figure_atomic, write_json_atomic

__all__ = ["Config", "run"]


@dataclasses.dataclass(frozen=True)
class DataConfig:
    stride: int = 4  # 120 Hz → 30 Hz
    walks: tuple[str, ...] = ("131_01", "131_09", "131_10", "131_11", "131_12", "131_13", "131_14")
    hand_actions: tuple[str, ...] = ("135_05", "135_10", "135_09")
    kicks: tuple[str, ...] = ("135_04", "135_07", "135_11")
    max_reps: int = 4  # repetitions taken per karate take
    half_window_s: float = 1.0  # upper-space window around the hand key time


@dataclasses.dataclass(frozen=True)
class SpaceConfig:
    n_samples: int = 1000
    k: int = 6
    concentration: float = 0.5
    max_active: int = 3


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    alphas: tuple[float, ...] = (0.0, 0.5, 1.0)
    alpha: float = 0.5  # the one written as BVH
    posture_transfer: float = 1.0
    n_queries: int = 20
    horn_k: int = 10
    timing_repeats: int = 5


@dataclasses.dataclass(frozen=True)
class Config:
    setups: tuple[str, ...] = ("walk_block", "kick_block")
    data: DataConfig = DataConfig()
    space: SpaceConfig = SpaceConfig()
    synth: SynthConfig = SynthConfig()

    def validate(self) -> None:
        for s in self.setups:
            if s not in ("walk_block", "kick_block"):
                raise ConfigError(
                    f"setups: unknown set-up {s!r}; choose walk_block and/or kick_block"
                )
        if self.data.stride < 1:
            raise ConfigError("data.stride must be >= 1")
        if not 0.0 <= self.synth.alpha <= 1.0 or any(not 0 <= a <= 1 for a in self.synth.alphas):
            raise ConfigError("synth.alpha and synth.alphas must lie in [0, 1]")
        if self.synth.horn_k < 3 or self.synth.horn_k > self.space.n_samples:
            raise ConfigError("synth.horn_k must be between 3 and space.n_samples")
        if self.space.k < 2:
            raise ConfigError("space.k must be at least 2 (k-NN interpolation)")


# ----------------------------------------------------------------------------- loading
def _load(take: str, stride: int) -> Motion:
    subj = take.split("_")[0]
    m = read_amc(
        data_path("body", "cmu", subj, f"{subj}.asf"),
        data_path("body", "cmu", subj, f"{take}.amc.gz"),
    )
    m = m.frames(slice(None, None, stride))
    # numpy arrays: the bookkeeping (key times, windows, alignment) then needs no compilation
    return dataclasses.replace(
        m,
        offsets=np.asarray(m.offsets),
        root_translation=np.asarray(m.root_translation),
        rotations=np.asarray(m.rotations),
    )


def _fk_fn(mot: Motion):
    parents = mot.parents
    offsets = jnp.asarray(mot.offsets)

    def fk(root, quats):
        return M.fk_arrays(parents, offsets, root, quats)[0]

    return jax.jit(fk)


def _relative(mot: Motion, X, j: int):
    """Joint ``j`` relative to the root, in the root's heading frame, per frame."""
    h = M.heading_quat(mot.rotations[:, 0])
    return M.quat_rotate(M.quat_conj(h), X[:, j] - X[:, 0])


_LOWER = ("lfemur", "ltibia", "lfoot", "ltoes", "rfemur", "rtibia", "rfoot", "rtoes")


def _lower_features_arrays(rot, X, idx: tuple[int, ...]) -> jnp.ndarray:
    """Lower-body joints ``idx`` relative to the root, in the root's heading frame, flattened
    (the DTW features: invariant to where the clip is and where it faces)."""
    h = M.heading_quat(rot[:, 0])
    rel = X[:, jnp.asarray(idx)] - X[:, :1]
    return M.quat_rotate(M.quat_conj(h)[:, None], rel).reshape(X.shape[0], -1)


def _lower_features(mot: Motion, X) -> jnp.ndarray:
    return _lower_features_arrays(mot.rotations, X, tuple(mot.index(n) for n in _LOWER))


# ----------------------------------------------------------------------------- spaces
@dataclasses.dataclass
class Space:
    ex: M.ExampleSet
    names: list[str]
    n_ref: int
    key_ref: float  # reference key time (frames), for the upper space / kicks
    weights: jnp.ndarray | None = None
    params: jnp.ndarray | None = None
    example_params: jnp.ndarray | None = None


def _walk_space(cfg: Config, skel: Motion, fk) -> tuple[Space, dict, Motion]:
    t_io = time.perf_counter()
    clips = [M.align_start(_load(t, cfg.data.stride)) for t in cfg.data.walks]
    t_io = time.perf_counter() - t_io
    for c in clips:
        if c.names != skel.names:
            raise ValueError("walk clips do not share the output skeleton's joints")
    lengths = [c.num_frames for c in clips]
    ref = int(np.argsort(lengths)[len(lengths) // 2])
    ex = M.stack_examples(
        [c.rotations for c in clips],
        [c.root_translation for c in clips],
        jnp.zeros((len(clips), lengths[ref])),
    )
    lens = ex.lengths

    @jax.jit
    def register(rot, root, lens):
        # batched FK + lower-body features + DTW of every example against the reference
        X = jax.vmap(fk)(root, rot)
        idx = tuple(skel.index(n) for n in _LOWER)
        F = jax.vmap(lambda r, x: _lower_features_arrays(r, x, idx))(rot, X)
        res = M.dtw_batch(F[ref], F, True, jnp.full_like(lens, lens[ref]), lens)
        return jax.vmap(lambda p: M.warp_from_path(p, lengths[ref]))(res.path), res.cost

    t0 = time.perf_counter()
    warps, _ = jax.block_until_ready(register(ex.rotations, ex.root, lens))
    reg = time.perf_counter() - t0
    t0 = time.perf_counter()
    warps, costs = jax.block_until_ready(register(ex.rotations, ex.root, lens))
    reg_run = time.perf_counter() - t0
    ex = ex._replace(warps=warps)
    space = Space(ex, list(cfg.data.walks), lengths[ref], float(lengths[ref] - 1))
    return (
        space,
        {
            "registration_s": reg,
            "registration_run_s": reg_run,
            "io_s": t_io,
            "reference": cfg.data.walks[ref],
            "frames": lengths,
            "dtw_costs": np.asarray(costs).tolist(),
        },
        clips[ref],
    )


def _hand_space(cfg: Config, skel: Motion, fk_out) -> tuple[Space, dict, Motion]:
    W = int(round(cfg.data.half_window_s * 30 * 4 / cfg.data.stride))
    rots, roots, keys, names, lens = [], [], [], [], []
    ref_clip = None
    io_s = 0.0
    t0 = time.perf_counter()
    for take in cfg.data.hand_actions:
        t_io = time.perf_counter()
        m = _load(take, cfg.data.stride)
        io_s += time.perf_counter() - t_io
        X = M.fk_arrays(m.parents, m.offsets, m.root_translation, m.rotations)[0]
        rel = _relative(m, X, m.index("lhand"))
        reach = np.linalg.norm(rel[:, [0, 2]], axis=1)
        for k in M.find_key_times(
            reach, min_separation=2 * W, max_keys=cfg.data.max_reps, margin=W // 2
        ):
            win = M.align_start(M.extract_window(m, k - W, k + W + 1))
            rots.append(win.rotations)
            roots.append(win.root_translation)
            keys.append(float(k - max(0, k - W)))
            lens.append(win.num_frames)
            names.append(f"{take}@{k}")
            if ref_clip is None:
                ref_clip = win
    n_ref = 2 * W + 1
    warps = np.stack(
        [
            M.keytime_warp(np.asarray([0.0, W, n_ref - 1.0]), np.asarray([0.0, k, n - 1.0]), n_ref)
            for k, n in zip(keys, lens, strict=True)
        ]
    )
    reg = time.perf_counter() - t0 - io_s
    ex = M.stack_examples(rots, roots, warps)
    return (
        Space(ex, names, n_ref, float(W)),
        {"registration_s": reg, "io_s": io_s, "examples": names},
        ref_clip,
    )


def _kick_space(cfg: Config, skel: Motion) -> tuple[Space, dict, Motion, list]:
    rots, roots, keysets, names, lens = [], [], [], [], []
    t0 = time.perf_counter()
    pad = int(round(0.25 * 120 / cfg.data.stride))
    clips = []
    io_s = 0.0
    for take in cfg.data.kicks:
        t_io = time.perf_counter()
        m = _load(take, cfg.data.stride)
        io_s += time.perf_counter() - t_io
        X = np.asarray(M.fk_arrays(m.parents, m.offsets, m.root_translation, m.rotations)[0])
        h = X[:, m.index("rtoes"), 1]
        floor = np.percentile(h, 10)
        sep = int(1.5 * 120 / cfg.data.stride)
        for apex in M.find_key_times(h, min_separation=sep, max_keys=cfg.data.max_reps, margin=pad):
            lift = apex
            while lift > 0 and h[lift] > floor + 0.1:
                lift -= 1
            land = apex
            while land < len(h) - 1 and h[land] > floor + 0.1:
                land += 1
            s, e = max(0, lift - pad), min(len(h), land + pad + 1)
            win = M.align_start(M.extract_window(m, s, e))
            clips.append(win)
            rots.append(win.rotations)
            roots.append(win.root_translation)
            keysets.append([0.0, lift - s, apex - s, land - s, e - s - 1.0])
            lens.append(e - s)
            names.append(f"{take}@{apex}")
    ref = int(np.argsort(lens)[len(lens) // 2])
    rk = np.asarray(keysets[ref])
    n_ref = lens[ref]
    warps = np.stack([M.keytime_warp(rk, np.asarray(k), n_ref) for k in keysets])
    reg = time.perf_counter() - t0 - io_s
    ex = M.stack_examples(rots, roots, warps)
    info = {"registration_s": reg, "io_s": io_s, "examples": names, "reference": names[ref]}
    return Space(ex, names, n_ref, float(keysets[ref][2])), info, clips[ref], keysets[ref]


# ----------------------------------------------------------------------------- parameters
def _param_fns(skel: Motion, lower_joint: str, lower_dims: tuple[int, ...], mask, spine: int):
    parents, offsets = skel.parents, jnp.asarray(skel.offsets)
    jl, jh = skel.index(lower_joint), skel.index("lhand")
    dims = jnp.asarray(lower_dims)

    def fk1(root, q):
        return M.fk_arrays(parents, offsets, root[None], q[None])[0][0]

    def lower_param(ex, w, u):
        q, r = M.blend_pose(ex, w, u)
        return fk1(r, q)[jl][dims]

    def upper_rel_param(ex, w, u):
        q, _ = M.blend_pose(ex, w, u)
        q = q.at[0].set(M.quat_mul(M.quat_conj(M.heading_quat(q[0])), q[0]))
        return fk1(jnp.zeros(3, q.dtype), q)[jh]

    def spliced_world_param(exL, wL, uL, exU, wU, uU, pt):
        qL, rL = M.blend_pose(exL, wL, uL)
        qU, _ = M.blend_pose(exU, wU, uU)
        q = M.splice_pose(qL, qU, mask, spine, pt)
        return fk1(rL, q)[jh]

    return lower_param, upper_rel_param, spliced_world_param, fk1


def _sample(space: Space, key, cfg: SpaceConfig, fn, u, n_queries: int):
    """Sample ``n_samples`` blends (the examples first) and ``n_queries`` fresh query blends
    and evaluate their parameters in one jitted, vmapped call (also used, with the same
    shapes, for the achieved parameters: one compilation per space)."""
    E = space.ex.warps.shape[0]
    S = max(cfg.n_samples, E)
    W = M.sample_blend_weights(key, E, S + n_queries, cfg.concentration, cfg.max_active)
    f = jax.jit(jax.vmap(lambda w: fn(space.ex, w, u)))
    jax.block_until_ready(f(W))  # compile
    t0 = time.perf_counter()
    P = jax.block_until_ready(f(W))
    dt = time.perf_counter() - t0
    space.weights, space.params, space.example_params = W[:S], P[:S], P[:E]
    return dt, f, W[S:], P[S:]


# ----------------------------------------------------------------------------- synthesis
def _synth_fn(exL, exU, lam, mask, spine, n_upper):
    def step(state, inp):
        clocks = state
        wL, wU, alpha, pt = inp
        qL, rL = M.blend_pose(exL, wL, clocks.u)
        qU, _ = M.blend_pose(exU, wU, clocks.v)
        q = M.splice_pose(qL, qU, mask, spine, pt)
        du = M.advance_clock(clocks.u, exL.warps, wL)
        dv = M.advance_clock(clocks.v, exU.warps, wU)
        nxt = M.sync_clocks(clocks, du, dv, lam, alpha, n_upper - 1.0)
        nxt = M.Clocks(jnp.minimum(nxt.u, exL.warps.shape[1] - 1.0), nxt.v)
        return nxt, (q, rL, clocks.u, clocks.v)

    return step


def _key_crossing_fn(exL, exU, lam, n_upper, key_ref, n_frames):
    """``u*``: the lower clock when the upper clock reaches ``key_ref`` (clocks only)."""

    def crossing(wL, wU, alpha):
        def step(c, _):
            du = M.advance_clock(c.u, exL.warps, wL)
            dv = M.advance_clock(c.v, exU.warps, wU)
            n = M.sync_clocks(c, du, dv, lam, alpha, n_upper - 1.0)
            n = M.Clocks(jnp.minimum(n.u, exL.warps.shape[1] - 1.0), n.v)
            return n, (n.u, n.v)

        z = jnp.asarray(0.0, wL.dtype)
        _, (us, vs) = jax.lax.scan(step, M.Clocks(z, z), None, length=n_frames)
        us = jnp.concatenate([z[None], us])
        vs = jnp.concatenate([z[None], vs])
        k = jnp.clip(jnp.argmax(vs >= key_ref), 1, n_frames)
        s = jnp.clip((key_ref - vs[k - 1]) / jnp.maximum(vs[k] - vs[k - 1], 1e-9), 0.0, 1.0)
        return us[k - 1] + s * (us[k] - us[k - 1])

    return crossing


def _synthesise(step, n_frames: int, v0: float = 0.0):
    """``run(wL, wU, alpha, pt)``: ``n_frames`` synthesised frames (a ``lax.scan`` of ``step``)."""

    def run(wL, wU, alpha, pt):
        init = M.Clocks(jnp.asarray(0.0, wL.dtype), jnp.asarray(v0, wL.dtype))
        inp = (wL, wU, jnp.asarray(alpha, wL.dtype), jnp.asarray(pt, wL.dtype))
        _, out = jax.lax.scan(lambda c, _: step(c, inp), init, None, length=n_frames)
        return out

    return run


def _foot_sliding(X, skel: Motion, rate: float) -> float:
    """Mean horizontal speed (m/s) of the toes while they touch the ground (height within
    3 cm of the clip's lowest toe height)."""
    out = []
    for n in ("ltoes", "rtoes"):
        p = np.asarray(X[:, skel.index(n)])
        h = p[:, 1]
        contact = (h[1:] < h.min() + 0.03) & (h[:-1] < h.min() + 0.03)
        v = np.linalg.norm(np.diff(p[:, [0, 2]], axis=0), axis=1) * rate
        if contact.any():
            out.append(v[contact].mean())
    return float(np.mean(out)) if out else float("nan")


def _timeit(f, *args, repeats=5):
    jax.block_until_ready(f(*args))
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def _run_setup(name: str, cfg: Config, run_dir: Path, key) -> dict:
    from fxspace import plot as P

    d, sc, sy = cfg.data, cfg.space, cfg.synth
    t_pre = time.perf_counter()
    if name == "walk_block":
        skel = M.align_start(_load(d.walks[0], d.stride))
        fk = _fk_fn(skel)
        lower, info_l, ref_l = _walk_space(cfg, skel, fk)
        lower_joint, dims, u_param = "ltoes", (0, 2), float(lower.n_ref - 1)
    else:
        skel = M.align_start(_load(d.kicks[0], d.stride))
        fk = _fk_fn(skel)
        lower, info_l, ref_l, ref_keys = _kick_space(cfg, skel)
        lower_joint, dims, u_param = "rtoes", (0, 1, 2), lower.key_ref
    upper, info_u, ref_u = _hand_space(cfg, skel, fk)
    mask = M.upper_body_mask(skel.parents, skel.names)
    spine = skel.index("lowerback")
    # alignment curve λ: lower reference frames → upper reference frames
    if name == "walk_block":
        fl = _lower_features(
            ref_l,
            M.fk_arrays(skel.parents, skel.offsets, ref_l.root_translation, ref_l.rotations)[0],
        )
        fu = _lower_features(
            ref_u,
            M.fk_arrays(skel.parents, skel.offsets, ref_u.root_translation, ref_u.rotations)[0],
        )
        M.dtw(fl, fu)  # compile
    t0 = time.perf_counter()
    if name == "walk_block":
        lam = M.warp_from_path(M.dtw(fl, fu).path, lower.n_ref)
    else:
        lam = M.keytime_warp(
            jnp.asarray([0.0, ref_keys[2], lower.n_ref - 1.0]),
            jnp.asarray([0.0, upper.key_ref, upper.n_ref - 1.0]),
            lower.n_ref,
        )
    reg_lam = time.perf_counter() - t0
    registration_s = (
        info_l.get("registration_run_s", info_l["registration_s"])
        + info_u["registration_s"]
        + reg_lam
    )
    registration_with_compile_s = info_l["registration_s"] + info_u["registration_s"] + reg_lam

    lower_param, upper_rel, spliced_world, fk1 = _param_fns(skel, lower_joint, dims, mask, spine)
    kL, kU, kq = jax.random.split(key, 3)
    io_s = info_l["io_s"] + info_u["io_s"]
    t_samp_l, fL, qWL, qPL = _sample(lower, kL, sc, lower_param, u_param, sy.n_queries)
    t_samp_u, fU, qWU, qPU = _sample(upper, kU, sc, upper_rel, upper.key_ref, sy.n_queries)
    preprocessing_s = time.perf_counter() - t_pre - io_s

    # queries: parameters of fresh random blends (inside the spaces), k-NN → weights → achieved
    EL, EU = lower.ex.warps.shape[0], upper.ex.warps.shape[0]
    knnL = jax.jit(
        jax.vmap(lambda p: M.knn_blend_weights(p, lower.params, lower.weights, sc.k).weights)
    )
    knnU = jax.jit(
        jax.vmap(lambda p: M.knn_blend_weights(p, upper.params, upper.weights, sc.k).weights)
    )
    wL_all, wU_all = knnL(qPL), knnU(qPU)
    achL = fL(jnp.concatenate([lower.weights, wL_all]))[-sy.n_queries :]
    achU = fU(jnp.concatenate([upper.weights, wU_all]))[-sy.n_queries :]
    errL = np.linalg.norm(np.asarray(achL - qPL), axis=1)
    errU = np.linalg.norm(np.asarray(achU - qPU), axis=1)
    # the nearest-example baseline (no blending)
    exP = np.asarray(lower.example_params)
    nnL = np.asarray([np.min(np.linalg.norm(exP - p, axis=1)) for p in np.asarray(qPL)])

    # synthesis
    n_frames = int(np.ceil(1.15 * lower.n_ref))
    step = _synth_fn(lower.ex, upper.ex, lam, mask, spine, upper.n_ref)
    run_fn = jax.jit(_synthesise(step, n_frames))
    wL, wU = wL_all[0], wU_all[0]
    clocks = {}
    for a in sy.alphas:
        _, _, us, vs = run_fn(wL, wU, a, sy.posture_transfer)
        clocks[a] = (np.asarray(us), np.asarray(vs))
    monotone = all(
        bool(np.all(np.diff(u) >= 0) and np.all(np.diff(v) >= 0)) for u, v in clocks.values()
    )
    t_scan = _timeit(run_fn, wL, wU, sy.alpha, sy.posture_transfer, repeats=sy.timing_repeats)
    q, r, us, vs = run_fn(wL, wU, sy.alpha, sy.posture_transfer)
    one = jax.jit(
        lambda c, wL, wU: (lambda o: (o[0], fk1(o[1][1], o[1][0])))(
            step(
                c,
                (
                    wL,
                    wU,
                    jnp.asarray(sy.alpha, wL.dtype),
                    jnp.asarray(sy.posture_transfer, wL.dtype),
                ),
            )
        )
    )
    c0 = M.Clocks(jnp.asarray(1.0, wL.dtype), jnp.asarray(1.0, wL.dtype))
    t_one = _timeit(one, c0, wL, wU, repeats=max(20, sy.timing_repeats))
    out = dataclasses.replace(skel, root_translation=r, rotations=q)
    X = np.asarray(fk(r, q))
    write_bvh(run_dir / f"{name}.bvh", out, scale=0.0254 / 0.45)
    off_np = np.asarray(skel.offsets)
    ex_slide = []
    for i in range(EL):  # numpy FK: no compilation per clip length
        n_i = int(lower.ex.lengths[i])
        Xi = M.fk_arrays(
            skel.parents,
            off_np,
            np.asarray(lower.ex.root[i, :n_i]),
            np.asarray(lower.ex.rotations[i, :n_i]),
        )[0]
        ex_slide.append(_foot_sliding(Xi, skel, skel.rate))
    slide = _foot_sliding(X, skel, skel.rate)

    # Horn re-placement. Each upper sample s reaches its key time at its own lower time
    # u*_s(wL, wU_s) (the clocks of eqs. 1-3 depend on both blends), so its world parameter
    # (left hand spliced onto the lower body) moves non-rigidly when wL changes.
    crossing = _key_crossing_fn(lower.ex, upper.ex, lam, upper.n_ref, upper.key_ref, n_frames)

    def world_params(wU_all, wL_, alpha):
        us = jax.vmap(lambda w: crossing(wL_, w, alpha))(wU_all)
        return jax.vmap(
            lambda w, u: spliced_world(
                lower.ex, wL_, u, upper.ex, w, upper.key_ref, sy.posture_transfer
            )
        )(wU_all, us)

    world_params = jax.jit(world_params)
    old = world_params(upper.weights, wL, sy.alpha)
    horn = []
    for i in range(1, min(6, sy.n_queries)):
        wL2 = wL_all[i]
        exact = world_params(upper.weights, wL2, sy.alpha)
        idx = jax.random.choice(
            jax.random.fold_in(kq, i), old.shape[0], (sy.horn_k,), replace=False
        )
        tf = M.absolute_orientation(old[idx], world_params(upper.weights[idx], wL2, sy.alpha))
        approx = M.apply_rigid(tf, old)
        e = np.linalg.norm(np.asarray(approx - exact), axis=1)
        horn.append(
            (e.mean(), e.max(), float(np.linalg.norm(np.asarray(old - exact), axis=1).mean()))
        )
    t_exact = _timeit(world_params, upper.weights, wL_all[1], sy.alpha, repeats=sy.timing_repeats)
    sub = upper.weights[: sy.horn_k]

    @jax.jit
    def horn_update(old, wL2):
        tf = M.absolute_orientation(old[: sy.horn_k], world_params(sub, wL2, sy.alpha))
        return M.apply_rigid(tf, old)

    t_horn = _timeit(horn_update, old, wL_all[1], repeats=sy.timing_repeats)

    # figures
    save_figure_atomic(
        P.plot_parameter_space(
            np.asarray(lower.params),
            np.asarray(lower.example_params),
            np.asarray(qPL),
            np.asarray(achL),
            title=f"{name}: lower-body space ({lower_joint})",
        ),
        run_dir / f"{name}_lower_space.png",
    )
    save_figure_atomic(
        P.plot_parameter_space(
            np.asarray(upper.params),
            np.asarray(upper.example_params),
            np.asarray(qPU),
            np.asarray(achU),
            title=f"{name}: upper-body space (lhand at key time)",
        ),
        run_dir / f"{name}_upper_space.png",
    )
    save_figure_atomic(
        P.plot_filmstrip(X, skel.parents, n_panels=8, title=f"{name} (α={sy.alpha})"),
        run_dir / f"{name}_filmstrip.png",
    )
    save_figure_atomic(
        P.plot_clocks(clocks, np.asarray(lam), title=f"{name}: clocks"),
        run_dir / f"{name}_clocks.png",
    )
    horn = np.asarray(horn)
    return {
        "n_lower_examples": EL,
        "n_upper_examples": EU,
        "lower_examples": lower.names,
        "upper_examples": upper.names,
        "n_samples": int(lower.weights.shape[0]),
        "registration_s": registration_s,
        "registration_with_compile_s": registration_with_compile_s,
        "io_s": io_s,
        "sampling_lower_s": t_samp_l,
        "sampling_upper_s": t_samp_u,
        "sampling_n": int(lower.weights.shape[0]) + sy.n_queries,
        "preprocessing_s": preprocessing_s,
        "lower_param_error_mean_m": float(errL.mean()),
        "lower_param_error_max_m": float(errL.max()),
        "lower_nearest_example_error_mean_m": float(nnL.mean()),
        "upper_param_error_mean_m": float(errU.mean()),
        "upper_param_error_max_m": float(errU.max()),
        "foot_sliding_m_per_s": slide,
        "foot_sliding_examples_m_per_s": float(np.nanmean(ex_slide)),
        "frames_synthesised": n_frames,
        "time_per_frame_scan_ms": 1e3 * t_scan / n_frames,
        "time_one_frame_jit_ms": 1e3 * t_one,
        "clocks_monotone_all_alphas": monotone,
        "horn_k": sy.horn_k,
        "horn_error_mean_m": float(horn[:, 0].mean()),
        "horn_error_max_m": float(horn[:, 1].max()),
        "no_update_error_mean_m": float(horn[:, 2].mean()),
        "exact_resample_s": t_exact,
        "horn_resample_s": t_horn,
    }


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
