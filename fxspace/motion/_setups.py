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

import time
from collections.abc import Callable
from typing import NamedTuple

import jax

from fxspace.errors import FxspaceError
from fxspace.motion._setup_config import (
    SetupData,
    SetupSpace,
    setup_labels,
    setup_takes,
)
from fxspace.motion._setup_examples import _idx, _kick_examples, _walk_examples
from fxspace.motion._space import stack_examples
from fxspace.motion._splice import upper_body_mask
from fxspace.motion._synthesis import SynthesisSpaces, build_spaces

__all__ = ["Setup", "prepare_setup"]


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


def _upper_axis(name: str, upper_labels: tuple[str, ...]) -> str:
    """The name of the mood walk's upper control axis, from its two clip labels."""
    if name != "mood_walk":
        return "left-hand position (root frame)"
    a, b = upper_labels[0], upper_labels[1] if len(upper_labels) > 1 else "other"
    return f"{a} weight ({b} = 1 − {a})"


def prepare_setup(
    name: str,
    load: Callable[[str], object],
    data: SetupData = SetupData(),  # noqa: B008 (frozen: one shared default is safe)
    space: SetupSpace = SetupSpace(),  # noqa: B008 (frozen)
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
