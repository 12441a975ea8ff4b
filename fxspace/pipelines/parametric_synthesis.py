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

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace._progress import note, progress
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io import Motion, read_amc, read_bvh, write_bvh
from fxspace.runs import cached, cached_arrays, run_key, save_figure_atomic, write_json_atomic

STAGES: tuple[str, ...] = ("setup", "targets", "timewarp", "session")
APP = "fxspace.studio._motion:serve"  # `fxspace studio` of a run: the motion app

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


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    alphas: tuple[float, ...] = (0.0, 0.5, 1.0)
    alpha: float = 0.5  # the one written as BVH
    n_queries: int = 20
    joy_weights: tuple[float, ...] = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)
    timing_repeats: int = 20
    session_s: float = 60.0  # the scripted continuous session (walks); 0 skips it
    session_every_s: float = 2.0  # controls changed this often


@dataclasses.dataclass(frozen=True)
class Config:
    setups: tuple[str, ...] = ("mood_walk", "block_walk", "block_kick")
    stride: int = 4  # CMU 120 Hz → 30 Hz (the Bandai clips are 30 Hz)
    data: M.SetupData = M.SetupData()
    space: M.SetupSpace = M.SetupSpace()
    synth: SynthConfig = SynthConfig()
    x64: bool = False  # run in float64 (jax.enable_x64 for the run only)
    skeleton: M.SkeletonSpec = M.SkeletonSpec()  # [skeleton] map = {role = "joint name"}

    def validate(self) -> None:
        for s in self.setups:
            if s not in M.SETUPS:
                raise ConfigError(f"setups: unknown set-up {s!r}; choose from {list(M.SETUPS)}")
        self.data.validate()
        self.skeleton.validate()
        if self.data.source == "files":
            if len(self.setups) != 1:
                raise ConfigError(
                    f"data.source = 'files' feeds one set-up; set setups to one of "
                    f"{list(M.SETUPS)}, got {list(self.setups)}"
                )
            n_up = sum(c.part == "upper" for c in self.data.clips)
            if self.setups[0] == "mood_walk" and n_up != 2:
                raise ConfigError(
                    f"data.clips: mood_walk weighs two upper-body walks (w and 1 − w; e.g. "
                    f"labels 'proud' and 'tired'), got {n_up} with part = 'upper'"
                )
            for c in self.data.clips:
                for key, f in (("path", c.path), ("asf", c.asf)):
                    if f and not Path(f).is_file():
                        what = "is a directory" if Path(f).is_dir() else "does not exist"
                        raise ConfigError(
                            f"data.clips: {key} {f} {what} (relative paths resolve against the "
                            "config file's folder)"
                        )
        if self.stride < 1:
            raise ConfigError("stride must be >= 1")
        if not 0.0 <= self.synth.alpha <= 1.0 or any(not 0 <= a <= 1 for a in self.synth.alphas):
            raise ConfigError("synth.alpha and synth.alphas must lie in [0, 1]")
        if not 3 <= self.space.k_replace <= self.space.n_samples:
            raise ConfigError("space.k_replace must be between 3 and space.n_samples")
        if self.space.splice not in ("heck", "heading"):
            raise ConfigError(
                f"space.splice must be 'heck' (spatial alignment + posture transfer, Heck et "
                f"al. 2006) or 'heading' (heading-relative spine copy), got {self.space.splice!r}"
            )
        if self.space.replace not in ("rotation", "rigid"):
            raise ConfigError(
                f"space.replace must be 'rotation' (§3.2 as printed: one rotation about the "
                f"root) or 'rigid' (rotation + translation), got {self.space.replace!r}"
            )
        if not 0.0 <= self.space.posture_transfer <= 1.0:
            raise ConfigError("space.posture_transfer must lie in [0, 1]")
        if self.space.knn_k < 2:
            raise ConfigError("space.knn_k must be at least 2 (k-NN interpolation)")
        if self.synth.n_queries < 2:
            raise ConfigError("synth.n_queries must be at least 2")
        if not self.synth.session_s >= 0 or not self.synth.session_every_s > 0:
            raise ConfigError("synth.session_s must be >= 0 and synth.session_every_s > 0")
        if not self.space.max_clock_rate > 0:
            raise ConfigError("space.max_clock_rate must be > 0 (inf: eqs. 2–3 uncapped)")
        if self.space.n_samples < 1 or self.data.cycles < 1 or self.data.max_reps < 1:
            raise ConfigError("space.n_samples, data.cycles and data.max_reps must be >= 1")


def take_files(take: str) -> list[Path]:
    """The data files of a clip: Bandai Namco ``dataset-…`` (one BVH) or CMU ``SSS_TT``
    (the subject's ASF and the take's AMC)."""
    if take.startswith("dataset-"):
        return [data_path("body", "bandai", f"{take}.bvh.gz")]
    subj = take.split("_")[0]
    return [data_path("body", "cmu", subj, f"{subj}.asf"),
            data_path("body", "cmu", subj, f"{take}.amc.gz")]  # fmt: skip


def _clip_asf(clip: M.SetupClip) -> Path:
    """An AMC clip's skeleton: its ``asf``, else ``<subject>.asf`` beside it (CMU-style
    ``SSS_TT.amc``), else the only ``.asf`` there."""
    if clip.asf:
        return Path(clip.asf)
    p = Path(clip.path)
    cand = p.parent / f"{p.name.split('_')[0].split('.')[0]}.asf"
    if cand.is_file():
        return cand
    asfs = sorted(p.parent.glob("*.asf"))
    if len(asfs) == 1:
        return asfs[0]
    raise ConfigError(
        f"data.clips: {clip.path}: an AMC needs its skeleton; set asf = \"…/subject.asf\" "
        f"({'none' if not asfs else len(asfs)} .asf beside it)"
    )


def _is_amc(path: str) -> bool:
    return path.lower().endswith((".amc", ".amc.gz"))


def data_files(cfg: Config) -> list[Path]:
    """The files a run reads (for its content key): every clip of every set-up, so a run
    (and its stored set-up) is never served after a clip changed on disk."""
    files: list[Path] = []
    if cfg.data.source == "files":
        for c in cfg.data.clips:
            for f in ([_clip_asf(c)] if _is_amc(c.path) else []) + [Path(c.path)]:
                files += [f] if f not in files else []
        return files
    for name in cfg.setups:
        for takes in M.setup_takes(name, cfg.data):
            for t in takes:
                files += [f for f in take_files(t) if f not in files]
    return files


def load_take(take: str, stride: int = 4) -> Motion:
    """A clip by take name: Bandai Namco ``dataset-…`` (BVH, cm, static root dropped) or CMU
    ``SSS_TT`` (ASF/AMC, every ``stride``-th frame)."""
    files = take_files(take)
    if take.startswith("dataset-"):
        return M.drop_root(read_bvh(files[0], scale=0.01))
    return read_amc(*files).frames(slice(None, None, stride))


def read_clip(
    clip: M.SetupClip,
    data: M.SetupData | None = None,
    stride: int = 4,
    skeleton: M.SkeletonSpec | None = None,
) -> tuple[Motion, dict]:
    """One's own clip (``[[data.clips]]``) in metres, and a record of what was read.

    A BVH's lengths are converted by its ``units`` (the clip's, else ``data.units``):
    declared (`fxspace.motion.LENGTH_UNITS` or metres per unit) or ``"auto"``, inferred by
    `fxspace.io.read_bvh` from the rest skeleton's size and checked against an adult's leg
    (a leg outside 0.59–1.15 m is refused, asking for the unit); a static root above the
    hips (Bandai Namco's ``joint_Root``) is dropped; every ``stride``-th frame is kept
    (the clip's ``stride``, else 1). An AMC is read with its ASF (`read_amc`, metres),
    every ``stride``-th frame (the clip's, else the config's). Says on the console what
    was read: file, label, frames, rate, units and how they were found, joint names.

    **Returns:** ``(motion, record)``: record keys ``path``, ``part``, ``label``, ``units``,
    ``units_from`` (``declared`` / ``inferred …``), ``metres_per_unit``, ``frames``,
    ``rate_hz``, ``stride``, ``joint_convention`` (and ``asf`` for an AMC).
    """
    data = M.SetupData() if data is None else data
    skeleton = M.SkeletonSpec() if skeleton is None else skeleton
    p = Path(clip.path)
    rec: dict = {"path": str(p), "part": clip.part, "label": clip.name}
    if _is_amc(clip.path):
        asf = _clip_asf(clip)
        k = clip.stride or stride
        m = read_amc(asf, p, rate=clip.rate or 120.0).frames(slice(None, None, k))
        jm = skeleton.joint_map(m.names, required=(), what=str(p))
        rec |= {"asf": str(asf), "units": "m", "units_from": "ASF (converted by read_amc)",
                "metres_per_unit": M.LENGTH_UNITS["cmu"], "stride": k}  # fmt: skip
    else:
        units = clip.units or data.units
        if isinstance(units, str) and units in _READ_BVH_UNITS:  # read_bvh converts, says so
            try:
                m = read_bvh(p, units=units)
            except FxspaceError as e:
                if isinstance(e, CorruptFileError) or units != "auto":
                    raise
                raise ConfigError(f"data.clips: {e}; {_DECLARE}") from None
            scale = None if units == "auto" else M.LENGTH_UNITS[units]
        else:  # the CMU unit, or metres per file unit
            scale = M.LENGTH_UNITS[units] if isinstance(units, str) else float(units)
            m = read_bvh(p, scale=scale)
        jm = skeleton.joint_map(m.names, required=(), what=str(p))
        if units == "auto":
            _check_leg(_leg_m(m, jm), p)
        if "hips" in jm and jm.index("hips") == 1 and m.parents.count(0) == 1:
            m = M.drop_root(m)  # a static root above the hips (Bandai Namco's joint_Root)
            jm = skeleton.joint_map(m.names, required=(), what=str(p))
        k = clip.stride or 1
        m = m.frames(slice(None, None, k))
        rec |= {"units": units, "metres_per_unit": scale, "stride": k,
                "units_from": "inferred by fxspace.io.read_bvh from the rest skeleton's size"
                if units == "auto" else "declared"}  # fmt: skip
    rec |= {"frames": m.num_frames, "rate_hz": float(m.rate), "joint_convention": jm.convention,
            "leg_m": _leg_m(m, jm)}  # fmt: skip
    note(
        f"{p.name}: {clip.part} clip {rec['label']!r}, {m.num_frames} frames at "
        f"{m.rate:.4g} Hz, units {rec['units']} ({rec['units_from']}), leg "
        f"{rec['leg_m']:.3g} m, joints: {jm.describe()}"
    )
    return m, rec


# the units fxspace.io.read_bvh converts itself (and says so on the console)
_READ_BVH_UNITS = ("auto", "m", "cm", "mm", "in", "ft")


def _leg_m(m: Motion, jm) -> float:
    """The left hip-to-ankle length (m) by role; NaN where the roles are missing."""
    off = np.asarray(m.offsets)
    roles = ("left_lower_leg", "left_foot")
    if not all(r in jm for r in roles):
        return float("nan")
    return float(sum(np.linalg.norm(off[jm.index(r)]) for r in roles))


def _check_leg(leg: float, path: Path) -> None:
    """A clip whose units were inferred must have an adult's leg once in metres."""
    if np.isfinite(leg) and not 0.82 / 1.4 <= leg <= 0.82 * 1.4:
        raise ConfigError(
            f"data.clips: {path}: with its units inferred (fxspace.io.read_bvh) its leg is "
            f"{leg:.3g} m, not an adult's (~0.8 m); {_DECLARE}"
        )


_DECLARE = (
    f"declare the file's unit on the clip or in [data]: units = one of {list(M.LENGTH_UNITS)} "
    "('cmu' for the CMU BVH conversion) or metres per file unit"
)


def _setup_loader(cfg: Config):
    """``(load(take) -> Motion, records)``: the config's clips by take name (defaults) or
    path (``source = "files"``); ``records`` fills with what was read."""
    records: dict = {}
    if cfg.data.source != "files":

        def load(take: str) -> Motion:
            records.setdefault(take, {"take": take, "files": [str(f) for f in take_files(take)]})
            return load_take(take, cfg.stride)

        return load, records
    clips = {c.path: c for c in cfg.data.clips}

    def load_file(path: str) -> Motion:
        m, rec = read_clip(clips[path], cfg.data, cfg.stride, cfg.skeleton)
        records.setdefault(path, rec)
        return m

    return load_file, records


def _build_setup(name: str, cfg: Config, key) -> M.Setup:
    """`fxspace.motion.prepare_setup` on the config's clips, with the config's joint map;
    the clips read (and, for one's own files, the units they are written back in) go to
    the set-up's ``info``."""
    load, records = _setup_loader(cfg)
    st = M.prepare_setup(name, load, cfg.data, cfg.space, key, joints=cfg.skeleton)
    info = {**st.info, "clips": list(records.values()), "data_source": cfg.data.source}
    if cfg.data.source == "files":
        lower = M.setup_takes(name, cfg.data)[0]
        # written back in the first lower clip's unit (metres where read_bvh inferred it)
        scale = records[lower[0]]["metres_per_unit"] or 1.0
        return st._replace(scale=float(scale), info=info)
    return st._replace(info=info)


_SETUPS: dict = {}


def load_setup(config: str | Path, setup: str | None = None) -> M.Setup:
    """The built set-up of a ``parametric_synthesis`` config file (or a run folder holding
    ``config.toml``), the same spaces `run` builds; ``setup`` picks one of its ``setups``
    (default the first). Kept in memory per file and modification time.

    A finished run folder's stored ``setup`` stage is read instead of rebuilt when the
    folder's cache is bound to this config, data and code (its ``cache/KEY`` equals the
    run key `fxspace run` would compute now): the studio opens in seconds, never on
    another config's spaces."""
    from fxspace.pipelines import resolve_config  # the package front, built after this module

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


# --------------------------------------------------------------------- stage: setup
_SP_ARRAYS = (
    "lam",
    "offsets",
    "lower_weights",
    "lower_params",
    "upper_weights",
    "upper_params",
    "lower_w0",
    "lower_time",
    "upper_time",
    "posture_transfer",
    "joint_steps",
)
_SP_META = (
    "parents",
    "mask",
    "spine",
    "lower_joint",
    "lower_dims",
    "upper_joint",
    "k_replace",
    "knn_k",
    "min_slope",
    "max_clock_rate",
    "splice",
    "torso",
    "replace",
)


def _setup_to_arrays(st: M.Setup) -> dict:
    sp, sk = st.spaces, st.skeleton
    arr = {f"lower_{k}": v for k, v in sp.lower._asdict().items()}
    arr |= {f"upper_{k}": v for k, v in sp.upper._asdict().items()}
    arr |= {k: getattr(sp, k) for k in _SP_ARRAYS}
    arr |= {"skel_offsets": sk.offsets, "skel_root": sk.root_translation, "skel_rot": sk.rotations}
    meta = {k: getattr(sp, k) for k in _SP_META}
    meta |= dict(
        name=st.name,
        names=sk.names,
        skel_parents=sk.parents,
        channels=sk.channels,
        rate=sk.rate,
        scale=st.scale,
        feet=st.feet,
        lower_names=st.lower_names,
        upper_names=st.upper_names,
        info=st.info,
    )
    arr["meta"] = np.asarray(json.dumps(meta))
    return arr


def _setup_from_arrays(a: dict) -> M.Setup:
    meta = json.loads(str(a["meta"]))
    ex = {
        s: M.ExampleSet(**{k: jnp.asarray(a[f"{s}_{k}"]) for k in M.ExampleSet._fields})
        for s in ("lower", "upper")
    }
    tup = {k: tuple(v) if isinstance(v, list) else v for k, v in meta.items() if k in _SP_META}
    if "joint_steps" not in a:  # a set-up stored before the joint-speed bound: derived
        a = {
            **a,
            "joint_steps": M.example_joint_steps(
                ex["lower"], ex["upper"], tuple(meta["parents"]), np.asarray(a["offsets"])
            ),
        }
    sp = M.SynthesisSpaces(**ex, **{k: jnp.asarray(a[k]) for k in _SP_ARRAYS}, **tup)
    skel = Motion(
        tuple(meta["names"]),
        tuple(meta["skel_parents"]),
        np.asarray(a["skel_offsets"]),
        np.asarray(a["skel_root"]),
        np.asarray(a["skel_rot"]),
        float(meta["rate"]),
        tuple(tuple(c) for c in meta["channels"]),
    )
    return M.Setup(
        meta["name"],
        sp,
        skel,
        float(meta["scale"]),
        tuple(meta["feet"]),
        meta["lower_names"],
        meta["upper_names"],
        meta["info"],
    )


def _stored_setup(run_dir: Path, name: str, cfg: Config) -> M.Setup | None:
    """``run_dir``'s stored ``setup`` stage if its cache is bound to the folder's own config,
    data and code (``cache/KEY`` = the run key computed now), else None."""
    import sys

    from fxspace.pipelines import _data_files

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


def _stage_setup(name: str, cfg: Config, run_dir: Path, key) -> M.Setup:
    def compute() -> dict:
        return _setup_to_arrays(_build_setup(name, cfg, jax.random.fold_in(key, 0)))

    return _setup_from_arrays(cached_arrays(run_dir, f"{name}_setup", compute))


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
        save_figure_atomic(_plot_fig3(st, extra["fig3"]), run_dir / f"{name}_fig3.png")


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


def _plot_fig3(st: M.Setup, f3: dict):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(11, 8))
    ax = axes[0]
    for i, (k, lab) in enumerate((("unaligned", "(a) clocks apart"),
                                  ("aligned_as_printed", "(b) eqs. 2–3 as printed"),
                                  ("aligned", "(b) eqs. 2–3, bounded (default)"))):  # fmt: skip
        c = f3[k][0]
        inside = c.lower_events[(c.lower_events >= c.upper_events[0])
                                & (c.lower_events <= c.upper_events[-1])]  # fmt: skip
        ax.plot(inside[: c.relative_phase.size], c.relative_phase, f"C{i}.-",
                label=f"{lab}: ratio {c.cycle_ratio:.3f}, drift {c.phase_drift:.2f}/min")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("arm-swing phase at each stride (cycles)")
    ax.legend(fontsize=7)
    feet, hands, hips = _gait_joints(st.skeleton)
    rate = float(st.skeleton.rate)
    for ax, k in zip(axes[1:], ("unaligned", "aligned"), strict=True):
        X = f3[k][1][: int(8 * rate)]
        t = np.arange(X.shape[0]) / rate
        ax.plot(t, M.swing_signal(X, feet[0], feet[1], hips), label="left foot − right foot")
        ax.plot(t, M.swing_signal(X, hands[1], hands[0], hips), label="right hand − left hand")
        ax.set_title(f"{'(a) clocks apart' if k == 'unaligned' else '(b) aligned'}: "
                     "forward offsets, first 8 s", fontsize=9)  # fmt: skip
        ax.set_xlabel("time (s)")
        ax.set_ylabel("m")
        ax.legend(fontsize=7)
    fig.suptitle(f"{st.name}: Fig. 3 read off the joints (arm swing against the strides)")
    fig.tight_layout()
    return fig


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
