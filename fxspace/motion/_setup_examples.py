"""A set-up's clips, cut and registered (`fxspace.motion.prepare_setup`): joints found by
role (`setup_roles`), walks cut to whole gait cycles of the left foot, karate hand
windows and kicks cut around their key times, every clip start-aligned and registered
against the first example (DTW for walks and hand raises, key times for karate).
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.joints import BODY_ROLES, JointMap, SkeletonSpec
from fxspace.motion._fk import fk_arrays
from fxspace.motion._register import alignment_curve, gait_window, pose_features, register_dtw
from fxspace.motion._space import extract_window, find_key_times
from fxspace.motion._splice import align_start, heading_quat
from fxspace.motion._timewarp import keytime_warp
from fxspace.rotations import quat_conj, quat_rotate

__all__ = ["setup_roles"]


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


def _as_spec(joints) -> SkeletonSpec:
    if joints is None:
        return SkeletonSpec()
    if isinstance(joints, SkeletonSpec):
        return joints
    if isinstance(joints, JointMap):
        return SkeletonSpec(map=joints.as_dict())
    if isinstance(joints, dict):
        return SkeletonSpec(map=dict(joints))
    raise FxspaceError(
        "joints must be a SkeletonSpec, a JointMap or a {role: joint name} dict, got "
        f"{type(joints).__name__}"
    )


def setup_roles(skeleton, joints=None, what: str = "the set-up's skeleton") -> dict:
    """The joints a set-up uses, found by role on ``skeleton`` (a `Motion`): ``split``
    (the upper body's root: the child of ``hips`` on the way to ``head``), ``lhand``,
    ``lfoot``, ``rtoe`` (``right_toes``, else ``right_foot``), ``feet`` (both toes, else
    feet), ``lower`` / ``upper`` (the registration features' joints) and ``map`` (the
    `JointMap`). ``joints``: a config's `SkeletonSpec`, a `JointMap` or ``{role: name}``."""
    if not all(hasattr(skeleton, a) for a in ("names", "parents")):
        raise FxspaceError(
            f"skeleton must be a Motion (joint names and parents), got {type(skeleton).__name__}"
        )
    jm = _as_spec(joints).joint_map(skeleton.names, required=BODY_ROLES, what=what)
    parents = skeleton.parents
    hips, j = jm.index("hips"), jm.index("head")
    chain = []
    while j >= 0 and j != hips:
        chain.append(j)
        j = parents[j]
    if j != hips or not chain:
        raise FxspaceError(
            f"{what}: the head ({jm['head']!r}) does not hang below the hips "
            f"({jm['hips']!r}); name the pelvis joint in the config: [skeleton] map = "
            '{hips = "…"}'
        )

    def toe(side: str) -> str:
        return jm.get(f"{side}_toes") or jm[f"{side}_foot"]

    legs = ("upper_leg", "lower_leg", "foot", "toes")
    return dict(
        split=skeleton.names[chain[-1]],
        lhand=jm["left_hand"],
        lfoot=jm["left_foot"],
        rtoe=toe("right"),
        feet=(toe("left"), toe("right")),
        lower=tuple(jm[f"{s}_{r}"] for s in ("left", "right") for r in legs if f"{s}_{r}" in jm),
        upper=tuple(jm[r] for r in ("left_hand", "left_lower_arm", "left_upper_arm",
                                    "right_hand", "right_lower_arm", "head")),
        map=jm,
    )  # fmt: skip


class _Loader:
    """``load(take)`` with every clip checked against the first: one skeleton (the same
    joints), one frame rate."""

    def __init__(self, load):
        self.load, self.first, self.first_take = load, None, None

    def __call__(self, take: str):
        m = _np(self.load(take))
        if self.first is None:
            self.first, self.first_take = m, take
            return m
        f = self.first
        if tuple(m.names) != tuple(f.names) or tuple(m.parents) != tuple(f.parents):
            only = [n for n in m.names if n not in f.names][:5]
            raise FxspaceError(
                f"clip {take}: its skeleton differs from {self.first_take}'s (joints "
                f"{only or 'in another order'}); every clip of a set-up must share one "
                "skeleton"
            )
        if not np.isclose(m.rate, f.rate, rtol=1e-3):
            raise FxspaceError(
                f"clip {take} runs at {m.rate:g} Hz and {self.first_take} at {f.rate:g} Hz; "
                "every clip of a set-up must share one rate (set the clips' stride)"
            )
        return m


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


def _walk_examples(name, load, data, lower_takes, upper_takes, joints) -> _Examples:
    """Walks (lower) and mood walks or hand raises (upper), DTW-registered."""
    t0 = time.perf_counter()
    load = _Loader(load)
    first = load(lower_takes[0])
    J = setup_roles(first, joints, f"clip {lower_takes[0]}")
    lows = [_walk(first if t == lower_takes[0] else load(t), J["lfoot"], data.cycles)
            for t in lower_takes]  # fmt: skip
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


def _kick_examples(name, load, data, lower_takes, upper_takes, joints) -> _Examples:
    """Karate: left-hand blocks (upper) and right-foot kicks (lower), registered by
    their key times (start, strike ↔ block, end)."""
    t0 = time.perf_counter()
    load = _Loader(load)
    first = load(upper_takes[0])
    J = setup_roles(first, joints, f"clip {upper_takes[0]}")
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
