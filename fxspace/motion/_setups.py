"""The three set-ups of Ha & Han's Table 1 on real captures, built from loaded clips.

- ``mood_walk``: upper = joy / sad walks, weights set by the user (no parameterisation);
  lower = direction walks/turns parameterised by the final left-foot position (x, z).
- ``block_walk``: upper = raise-left-hand clips parameterised by the left-hand position at
  the key time (root frame); lower = the direction walks.
- ``block_kick``: upper = left-hand blocks/punches; lower = right-foot kicks parameterised
  by the right-toe position at the strike; key-time alignment (3 key times: start, block ↔
  strike, end).

Clips are read by the caller (``load(take) -> Motion``; this module does no file I/O), so
the pipelines and the studio share one construction. Walks are cut to whole gait cycles of
the left foot (`gait_window`), every clip is start-aligned, and each set is registered
against its first example ``M_1`` (DTW of lower-body features for walks, of upper-body
features for the hand clips, key times for the karate clips).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Literal, NamedTuple

import jax
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.motion._fk import fk_arrays
from fxspace.motion._register import alignment_curve, gait_window, pose_features, register_dtw
from fxspace.motion._space import extract_window, find_key_times, stack_examples
from fxspace.motion._splice import align_start, heading_quat, upper_body_mask
from fxspace.motion._synthesis import SynthesisSpaces, build_spaces
from fxspace.motion._timewarp import keytime_warp
from fxspace.rotations import quat_conj, quat_rotate

__all__ = [
    "SetupName",
    "SETUPS",
    "SetupData",
    "SetupSpace",
    "Setup",
    "prepare_setup",
    "setup_takes",
]

SetupName = Literal["mood_walk", "block_walk", "block_kick"]
SETUPS: tuple[str, ...] = ("mood_walk", "block_walk", "block_kick")

_B = "dataset-2_walk"
_WALKS = tuple(
    [f"{_B}_normal_00{i}" for i in (1, 2, 3, 4)]
    + [f"{_B}-turn-left_normal_00{i}" for i in (1, 2, 3, 4)]
    + [f"{_B}-turn-right_normal_00{i}" for i in (1, 2, 3, 4)]
)
DEFAULTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mood_walk": (_WALKS[:2] + _WALKS[4:], ("dataset-1_walk_happy_001", "dataset-1_walk_sad_001")),
    "block_walk": (_WALKS, tuple(f"dataset-2_raise-up-left-hand_normal_{i:03d}"
                                 for i in range(1, 13))),
    "block_kick": (("135_04", "135_07", "135_11"), ("135_05", "135_10", "135_09")),
}  # fmt: skip

# joint names of the two skeletons (Bandai Namco BVH, CMU ASF)
_NAMES = {
    "bandai": dict(
        spine="Spine", lhand="Hand_L", lfoot="Foot_L", rtoe="Toes_R", feet=("Toes_L", "Toes_R"),
        lower=("UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L", "UpperLeg_R", "LowerLeg_R",
               "Foot_R", "Toes_R"),
        upper=("Hand_L", "LowerArm_L", "UpperArm_L", "Hand_R", "LowerArm_R", "Head"),
    ),
    "cmu": dict(
        spine="lowerback", lhand="lhand", lfoot="lfoot", rtoe="rtoes", feet=("ltoes", "rtoes"),
        lower=("lfemur", "ltibia", "lfoot", "ltoes", "rfemur", "rtibia", "rfoot", "rtoes"),
        upper=("lhand", "lradius", "lhumerus", "rhand", "rradius", "head"),
    ),
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SetupData:
    """Clips of a set-up (empty: the set-up's defaults) and how they are cut."""

    lower: tuple[str, ...] = ()
    upper: tuple[str, ...] = ()
    cycles: int = 2  # gait cycles per walk clip
    max_reps: int = 4  # repetitions taken per karate take
    half_window_s: float = 1.0  # karate hand window around its key time


@dataclasses.dataclass(frozen=True)
class SetupSpace:
    """Sampling of both spaces (Kovar & Gleicher) and §3.2's re-placement ``k``."""

    n_samples: int = 1000
    knn_k: int = 6
    k_replace: int = 10
    concentration: float = 0.5
    max_active: int = 3
    posture_transfer: float = 1.0
    splice: str = "heck"  # "heck": spatial alignment + posture transfer; "heading"
    replace: str = "rotation"  # §3.2: "rotation" about the root (as printed) or "rigid"
    min_slope: float = 0.05
    max_clock_rate: float = 1.0  # eqs. 2–3 never rush a clock past this × its own rate


class Setup(NamedTuple):
    """Built spaces plus what an application needs: ``skeleton`` (a Motion of one frame,
    for names/parents/offsets/channels/rate), ``scale`` (metres per file unit, for BVH),
    ``feet`` (toe joint indices), ``lower_names``/``upper_names``, ``info`` (timings:
    ``registration_s``, ``sampling_s``; reference clips)."""

    name: str
    spaces: SynthesisSpaces
    skeleton: object
    scale: float
    feet: tuple[int, int]
    lower_names: list[str]
    upper_names: list[str]
    info: dict


def _np(m):
    return dataclasses.replace(
        m,
        offsets=np.asarray(m.offsets),
        root_translation=np.asarray(m.root_translation),
        rotations=np.asarray(m.rotations),
    )


def _fk(m):
    return fk_arrays(m.parents, m.offsets, m.root_translation, m.rotations)[0]


def _walk(m, foot: str, cycles: int):
    """``cycles`` gait cycles cut at mid-stance of ``foot`` (0.2 s after its touch-down,
    where the foot is flat and still, so a wrapping cycle shows no seam)."""
    shift = int(round(0.2 * m.rate))
    try:
        w = gait_window(m, foot, cycles, skip=1, shift=shift)
    except ValueError:
        w = gait_window(m, foot, cycles, skip=0, shift=shift)
    return align_start(_np(w))


def _idx(m, names) -> tuple[int, ...]:
    return tuple(m.index(n) for n in names)


def _hand_reach(m, hand: str) -> np.ndarray:
    X = _fk(m)
    h = heading_quat(m.rotations[:, 0])
    rel = np.asarray(quat_rotate(quat_conj(h), X[:, m.index(hand)] - X[:, 0]))
    return rel


def _karate_hands(takes, load, J, W: int, max_reps: int):
    clips, keys = [], []
    for take in takes:
        m = _np(load(take))
        rel = _hand_reach(m, J["lhand"])
        reach = np.linalg.norm(rel[:, [0, 2]], axis=1)
        for k in find_key_times(reach, min_separation=2 * W, max_keys=max_reps, margin=W // 2):
            clips.append(align_start(extract_window(m, k - W, k + W + 1)))
            keys.append(float(k - max(0, k - W)))
    return clips, keys


def _kicks(takes, load, J, max_reps: int, rate: float):
    clips, keysets = [], []
    pad = int(round(0.25 * rate))
    for take in takes:
        m = _np(load(take))
        h = np.asarray(_fk(m)[:, m.index(J["rtoe"]), 1])
        floor = np.percentile(h, 10)
        for apex in find_key_times(h, int(1.5 * rate), max_keys=max_reps, margin=pad):
            lift, land = apex, apex
            while lift > 0 and h[lift] > floor + 0.1:
                lift -= 1
            while land < len(h) - 1 and h[land] > floor + 0.1:
                land += 1
            s, e = max(0, lift - pad), min(len(h), land + pad + 1)
            clips.append(align_start(extract_window(m, s, e)))
            keysets.append([0.0, lift - s, apex - s, land - s, e - s - 1.0])
    return clips, keysets


def setup_takes(name: str, data: SetupData = SetupData()) -> tuple[tuple[str, ...], ...]:
    """``(lower takes, upper takes)`` the set-up ``name`` reads: ``data``'s, else its
    defaults (Bandai ``dataset-…`` or CMU ``SSS_TT`` names)."""
    if not isinstance(name, str) or name not in SETUPS:
        raise FxspaceError(f"unknown set-up {name!r}; choose one of {list(SETUPS)}")
    if not isinstance(data, SetupData):
        raise FxspaceError(f"data must be a SetupData, got {type(data).__name__}")
    return tuple(data.lower or DEFAULTS[name][0]), tuple(data.upper or DEFAULTS[name][1])


class _Examples(NamedTuple):
    """A set-up's clips, registered: what `prepare_setup` builds its spaces from."""

    J: dict
    lows: list
    ups: list
    warps_l: object
    warps_u: object
    lam: object
    upper_joint: int
    upper_time: float
    lower_joint: int
    lower_time: float
    dims: tuple
    scale: float
    io_s: float
    registration_s: float


def _bandai_examples(name, load, data, lower_takes, upper_takes) -> _Examples:
    """Bandai Namco walks (lower) and mood walks or hand raises (upper), DTW-registered."""
    t0 = time.perf_counter()
    J = _NAMES["bandai"]
    lows = [_walk(load(t), J["lfoot"], data.cycles) for t in lower_takes]
    skel = lows[0]
    t_io = time.perf_counter() - t0
    t0 = time.perf_counter()
    fl = [np.asarray(pose_features(c, _idx(c, J["lower"]))) for c in lows]
    warps_l = register_dtw(fl, 9, cyclic=True)
    if name == "mood_walk":
        ups = [_walk(load(t), J["lfoot"], data.cycles) for t in upper_takes]
        fu = [np.asarray(pose_features(c, _idx(c, J["lower"]))) for c in ups]
        warps_u = register_dtw(fu, 9, cyclic=True)
        lam = alignment_curve(fl[0], fu[0], 9, cyclic=True)
        upper_joint, upper_time = -1, 0.0
    else:
        ups = [align_start(_np(load(t))) for t in upper_takes]
        fu = [np.asarray(pose_features(c, _idx(c, J["upper"]))) for c in ups]
        warps_u = register_dtw(fu)
        upper_time = float(np.argmax(_hand_reach(ups[0], J["lhand"])[:, 1]))
        n_l, n_u = fl[0].shape[0], fu[0].shape[0]
        lam = keytime_warp(np.asarray([0.0, n_l - 1.0]), np.asarray([0.0, n_u - 1.0]), n_l)
        upper_joint = skel.index(J["lhand"])
    return _Examples(J, lows, ups, warps_l, warps_u, lam, upper_joint, upper_time,
                     skel.index(J["lfoot"]), float(fl[0].shape[0] - 1), (0, 2), 0.01,
                     t_io, time.perf_counter() - t0)  # fmt: skip


def _cmu_examples(name, load, data, lower_takes, upper_takes) -> _Examples:
    """CMU karate: left-hand blocks (upper) and right-foot kicks (lower), registered by
    their key times (start, strike ↔ block, end)."""
    t0 = time.perf_counter()
    J = _NAMES["cmu"]
    first = _np(load(upper_takes[0]))
    W = int(round(data.half_window_s * first.rate))
    ups, ukeys = _karate_hands(upper_takes, load, J, W, data.max_reps)
    lows, lkeys = _kicks(lower_takes, load, J, data.max_reps, first.rate)
    skel = lows[0]
    t_io = time.perf_counter() - t0
    t0 = time.perf_counter()
    n_u, n_l = ups[0].num_frames, lows[0].num_frames
    ref_keys = np.asarray([0.0, ukeys[0], n_u - 1.0])
    warps_u = np.stack(
        [
            keytime_warp(ref_keys, np.asarray([0.0, k, c.num_frames - 1.0]), n_u)
            for k, c in zip(ukeys, ups, strict=True)
        ]
    )
    rk = np.asarray(lkeys[0])
    warps_l = np.stack([keytime_warp(rk, np.asarray(k), n_l) for k in lkeys])
    upper_time, lower_time = ukeys[0], float(rk[2])
    lam = keytime_warp(  # 3 key times: start, strike ↔ block, end
        np.asarray([0.0, rk[2], n_l - 1.0]), np.asarray([0.0, upper_time, n_u - 1.0]), n_l
    )
    return _Examples(J, lows, ups, warps_l, warps_u, lam, skel.index(J["lhand"]), upper_time,
                     skel.index(J["rtoe"]), lower_time, (0, 1, 2), 0.0254 / 0.45,
                     t_io, time.perf_counter() - t0)  # fmt: skip


def prepare_setup(
    name: str,
    load: Callable[[str], object],
    data: SetupData = SetupData(),
    space: SetupSpace = SetupSpace(),
    key: jax.Array | None = None,
) -> Setup:
    """Load, cut, register and sample the set-up ``name`` (one of `SETUPS`).

    **Arguments:** ``load(take)`` returns a `Motion` (Bandai takes are
    ``dataset-…``, CMU ones ``SSS_TT``); ``data``/``space`` configure clips and sampling;
    ``key`` the sampling PRNG key (default ``PRNGKey(0)``).

    **Returns:** a `Setup` (spaces ready for `synthesize_step`).
    """
    lower_takes, upper_takes = setup_takes(name, data)
    key = jax.random.PRNGKey(0) if key is None else key
    pick = _bandai_examples if name in ("mood_walk", "block_walk") else _cmu_examples
    e = pick(name, load, data, lower_takes, upper_takes)
    J, lows, ups, skel, t_io = e.J, e.lows, e.ups, e.lows[0], e.io_s
    lam, scale, dims = e.lam, e.scale, e.dims
    t0 = time.perf_counter()
    exL = stack_examples([c.rotations for c in lows], [c.root_translation for c in lows], e.warps_l)
    exU = stack_examples([c.rotations for c in ups], [c.root_translation for c in ups], e.warps_u)
    registration_s = e.registration_s + time.perf_counter() - t0
    t0 = time.perf_counter()
    sp = build_spaces(
        exL,
        exU,
        lam,
        skel.parents,
        skel.offsets,
        mask=upper_body_mask(skel.parents, skel.names, J["spine"]),
        spine=skel.index(J["spine"]),
        lower_joint=e.lower_joint,
        lower_dims=dims,
        lower_time=e.lower_time,
        upper_joint=e.upper_joint,
        upper_time=e.upper_time,
        key=key,
        n_samples=space.n_samples,
        knn_k=space.knn_k,
        k_replace=space.k_replace,
        posture_transfer=space.posture_transfer,
        splice=space.splice,
        replace=space.replace,
        concentration=space.concentration,
        max_active=space.max_active,
        min_slope=space.min_slope,
        max_clock_rate=space.max_clock_rate,
    )
    jax.block_until_ready(sp.upper_params)
    sampling_s = time.perf_counter() - t0
    info = {
        "io_s": t_io,
        "registration_s": registration_s,
        "sampling_s": sampling_s,
        "lower_reference": lower_takes[0],
        "upper_reference": upper_takes[0],
        "n_lower_examples": len(lows),
        "n_upper_examples": len(ups),
    }
    return Setup(
        name,
        sp,
        skel.frames(slice(0, 1)),
        scale,
        _idx(skel, J["feet"]),
        [str(t) for t in lower_takes],
        [str(t) for t in upper_takes],
        info,
    )
