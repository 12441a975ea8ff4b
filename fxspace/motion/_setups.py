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

Joints are found by role (`fxspace.motion.joint_map_for`), not by name: the upper/lower
split is the child of ``hips`` on the way to ``head``, the gait foot ``left_foot``, the
hand ``left_hand``, the kick toe ``right_toes`` (or ``right_foot``), so a CMU, Bandai
Namco, ``LeftUpLeg``-style (Mixamo), VRM or SMPL skeleton drives every set-up; a config's
``[skeleton] map`` names joints the conventions miss. Clips come from the defaults above
or, with ``SetupData(source="files", clips=...)``, from one's own files (`SetupClip`:
path, lower/upper part, label), labelled in the set-up's ``info``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Literal, NamedTuple

import jax
import numpy as np

from fxspace.config import ConfigError
from fxspace.errors import FxspaceError
from fxspace.joints import BODY_ROLES, JointMap, SkeletonSpec
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
    "SetupClip",
    "SetupData",
    "SetupSpace",
    "Setup",
    "prepare_setup",
    "setup_takes",
    "setup_labels",
    "setup_roles",
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

# labels of the default clips where the take name does not say it (Ha & Han's mood walk)
DEFAULT_LABELS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mood_walk": ((), ("joy", "sad")),
}
_CLIP_SUFFIXES = (".bvh", ".bvh.gz", ".amc", ".amc.gz")


@dataclasses.dataclass(frozen=True)
class SetupClip:
    """One of one's own clips (``[[data.clips]]`` of a config; ``SetupData.source =
    "files"``).

    - ``path``: a BVH (``.bvh``, ``.bvh.gz``) or an AMC (``.amc``, ``.amc.gz``) file.
    - ``part``: ``"lower"`` (the lower-body examples: walks, kicks) or ``"upper"`` (the
      upper body: moods, hand raises, blocks).
    - ``label``: what the clip is (``"proud"``); default the file name. The mood walk's
      two upper labels name its weight axis (``"proud weight (tired = 1 − proud)"``).
    - ``asf``: an AMC's skeleton (default ``<subject>.asf`` beside it, CMU-style).
    - ``units``: a BVH's length unit (`fxspace.motion.LENGTH_UNITS` name, or metres per
      file unit); ``""``: the data table's ``units``.
    - ``stride``: keep every ``stride``-th frame (0: the config's ``stride`` for AMC, 1 for
      BVH); ``rate``: an AMC's frame rate (0: CMU's 120 Hz).
    """

    path: str
    part: Literal["lower", "upper"] = "lower"
    label: str = ""
    asf: str = ""
    units: str | float = ""
    stride: int = 0
    rate: float = 0.0

    def validate(self) -> None:
        if not isinstance(self.path, str) or not self.path.lower().endswith(_CLIP_SUFFIXES):
            raise ConfigError(
                f"data.clips: path {self.path!r} must be a BVH (.bvh, .bvh.gz) or an AMC "
                "(.amc, .amc.gz) file"
            )
        if self.part not in ("lower", "upper"):
            raise ConfigError(
                f"data.clips: {self.path}: part must be 'lower' or 'upper', got {self.part!r}"
            )
        _check_units(self.units, f"data.clips: {self.path}: units", allow_empty=True)
        if self.stride < 0 or not self.rate >= 0:
            raise ConfigError(f"data.clips: {self.path}: stride and rate must be >= 0")

    @property
    def name(self) -> str:
        """The label, else the file name without its extension."""
        if self.label:
            return self.label
        base = self.path.replace("\\", "/").rsplit("/", 1)[-1]
        for suf in sorted(_CLIP_SUFFIXES, key=len, reverse=True):
            if base.lower().endswith(suf):
                return base[: -len(suf)]
        return base


def _check_units(units, where: str, allow_empty: bool = False) -> None:
    from fxspace.joints import LENGTH_UNITS

    if isinstance(units, str):
        if units in LENGTH_UNITS or units == "auto" or (allow_empty and units == ""):
            return
    elif isinstance(units, int | float) and not isinstance(units, bool) and units > 0:
        if np.isfinite(units):
            return
    raise ConfigError(
        f"{where} must be 'auto' (inferred from the skeleton's size), one of "
        f"{list(LENGTH_UNITS)} or metres per file unit (a positive number), got {units!r}"
    )


@dataclasses.dataclass(frozen=True)
class SetupData:
    """Clips of a set-up and how they are cut.

    - ``source``: ``"default"`` (the set-up's Bandai Namco / CMU takes under the data root,
      or those named by ``lower`` / ``upper``) or ``"files"`` (``clips``, one's own).
    - ``lower`` / ``upper``: take names (``source = "default"``; empty: the defaults).
    - ``clips``: `SetupClip` entries (``source = "files"``).
    - ``units``: the BVH files' length unit: ``"auto"`` (inferred by `fxspace.io.read_bvh`
      from the skeleton's size, said on the console, checked against an adult's leg), a
      `fxspace.motion.LENGTH_UNITS` name (``"cm"`` for Bandai Namco, ``"cmu"`` for the CMU
      BVH conversion) or metres per file unit.
    """

    lower: tuple[str, ...] = ()
    upper: tuple[str, ...] = ()
    cycles: int = 2  # gait cycles per walk clip
    max_reps: int = 4  # repetitions taken per karate take
    half_window_s: float = 1.0  # karate hand window around its key time
    source: Literal["default", "files"] = "default"
    clips: tuple[SetupClip, ...] = ()
    units: str | float = "auto"

    def validate(self) -> None:
        if self.source not in ("default", "files"):
            raise ConfigError(f"data.source must be 'default' or 'files', got {self.source!r}")
        _check_units(self.units, "data.units")
        if self.source == "files":
            if self.lower or self.upper:
                raise ConfigError(
                    "data.lower / data.upper name default takes; with data.source = 'files' "
                    "list the clips as data.clips = [{path = ..., part = 'lower'}, ...]"
                )
            parts = {c.part for c in self.clips}
            if parts != {"lower", "upper"}:
                raise ConfigError(
                    "data.source = 'files' needs data.clips with part = 'lower' and part = "
                    f"'upper' clips, e.g. [[data.clips]] path = 'walk_01.bvh', part = 'lower'; "
                    f"got parts {sorted(parts)}"
                )
            for c in self.clips:
                c.validate()
            paths = [c.path for c in self.clips]
            dup = sorted({p for p in paths if paths.count(p) > 1})
            if dup:
                raise ConfigError(f"data.clips lists {dup} more than once")
        elif self.clips:
            raise ConfigError("data.clips are read with data.source = 'files'; set it")


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
    """``(lower takes, upper takes)`` the set-up ``name`` reads: the clip paths of
    ``data.clips`` (``source = "files"``), ``data``'s take names, else its defaults
    (Bandai ``dataset-…`` or CMU ``SSS_TT`` names)."""
    if not isinstance(name, str) or name not in SETUPS:
        raise FxspaceError(f"unknown set-up {name!r}; choose one of {list(SETUPS)}")
    if not isinstance(data, SetupData):
        raise FxspaceError(f"data must be a SetupData, got {type(data).__name__}")
    if data.source == "files":
        return tuple(
            tuple(c.path for c in data.clips if c.part == part) for part in ("lower", "upper")
        )
    return tuple(data.lower or DEFAULTS[name][0]), tuple(data.upper or DEFAULTS[name][1])


def setup_labels(name: str, data: SetupData = SetupData()) -> tuple[tuple[str, ...], ...]:
    """``(lower labels, upper labels)``, one per take of `setup_takes`: the clips'
    ``label`` (else their file names) for ``source = "files"``; the mood walk's default
    upper clips are ``("joy", "sad")``; other takes are labelled by their names."""
    lower, upper = setup_takes(name, data)
    if data.source == "files":
        return tuple(
            tuple(c.name for c in data.clips if c.part == part) for part in ("lower", "upper")
        )
    out = []
    for takes, default, labels in zip(
        (lower, upper), DEFAULTS[name], DEFAULT_LABELS.get(name, ((), ())), strict=True
    ):
        out.append(tuple(labels) if labels and takes == default else tuple(takes))
    return out[0], out[1]


def _upper_axis(name: str, upper_labels: tuple[str, ...]) -> str:
    """The name of the mood walk's upper control axis, from its two clip labels."""
    if name != "mood_walk":
        return "left-hand position (root frame)"
    a, b = upper_labels[0], upper_labels[1] if len(upper_labels) > 1 else "other"
    return f"{a} weight ({b} = 1 − {a})"


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


def prepare_setup(
    name: str,
    load: Callable[[str], object],
    data: SetupData = SetupData(),
    space: SetupSpace = SetupSpace(),
    key: jax.Array | None = None,
    *,
    joints=None,
    scale: float | None = None,
) -> Setup:
    """Load, cut, register and sample the set-up ``name`` (one of `SETUPS`).

    **Arguments:** ``load(take)`` returns a `Motion` in metres for each take of
    `setup_takes` (Bandai takes are ``dataset-…``, CMU ones ``SSS_TT``, one's own clips
    their paths); ``data``/``space`` configure clips and sampling; ``key`` the sampling
    PRNG key (default ``PRNGKey(0)``); ``joints`` a config's `SkeletonSpec` (or a
    `JointMap`, or ``{role: joint name}``) for skeletons whose names no convention of
    `fxspace.motion.joint_map_for` covers; ``scale`` the metres per unit of the BVH files
    the set-up writes (default: the Bandai Namco cm for the walks, the CMU ASF unit for
    the kicks).

    **Returns:** a `Setup` (spaces ready for `synthesize_step`); its ``info`` names the
    clips' labels (``lower_labels``, ``upper_labels``), the mood walk's weight axis
    (``upper_axis``) and the joint map (``joint_map``: role → joint, ``joint_convention``).
    """
    lower_takes, upper_takes = setup_takes(name, data)
    if not lower_takes or not upper_takes:
        raise FxspaceError(
            f"set-up {name} needs lower and upper clips, got {len(lower_takes)} lower and "
            f"{len(upper_takes)} upper"
        )
    if name == "mood_walk" and len(upper_takes) != 2:
        raise FxspaceError(
            f"mood_walk weighs two upper-body walks (w and 1 − w), got {len(upper_takes)} "
            f"upper clips {list(upper_takes)}; give exactly two"
        )
    lower_labels, upper_labels = setup_labels(name, data)
    key = jax.random.PRNGKey(0) if key is None else key
    pick = _walk_examples if name in ("mood_walk", "block_walk") else _kick_examples
    e = pick(name, load, data, lower_takes, upper_takes, joints)
    J, lows, ups, skel, t_io = e.J, e.lows, e.ups, e.lows[0], e.io_s
    lam, dims = e.lam, e.dims
    scale = e.scale if scale is None else float(scale)
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
        mask=upper_body_mask(skel.parents, skel.names, J["split"]),
        spine=skel.index(J["split"]),
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
        "lower_labels": list(lower_labels),
        "upper_labels": list(upper_labels),
        "upper_axis": _upper_axis(name, upper_labels),
        "joint_convention": J["map"].convention,
        "joint_map": J["map"].as_dict(),
        "upper_root": J["split"],
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
