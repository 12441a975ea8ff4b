"""Registration for decoupled synthesis (Ha & Han §3.1): frame features, DTW warps against
the first example ``M_1``, alignment curves ``λ`` between two reference clips, and small
clip utilities (dropping a static root joint, cutting gait cycles)."""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.motion._dtw import dtw, dtw_batch, warp_from_path
from fxspace.motion._fk import fk_arrays
from fxspace.motion._splice import heading_quat
from fxspace.results import (
    RESULTS,
    check_result,
    is_successful,
    member_code,
    result_code,
    result_from_flags,
)
from fxspace.rotations import quat_conj, quat_mul, quat_rotate

if TYPE_CHECKING:
    from fxspace.motion._types import Motion

__all__ = [
    "pose_features",
    "register_dtw",
    "register_examples",
    "RegistrationResult",
    "alignment_curve",
    "smooth_warp",
    "drop_root",
    "gait_window",
]


@checked
def pose_features(motion: Motion, joints: tuple[int, ...]) -> Float[Array, "T d"]:
    """Per-frame features for DTW: joints ``joints`` relative to the root, expressed in the
    root's heading frame (yaw only), flattened — invariant to where the clip is on the
    ground and where it faces."""
    X = fk_arrays(motion.parents, motion.offsets, motion.root_translation, motion.rotations)[0]
    h = heading_quat(motion.rotations[:, 0])
    rel = X[:, np.asarray(joints)] - X[:, :1]
    return quat_rotate(quat_conj(h)[:, None], rel).reshape(X.shape[0], -1)


@checked
def smooth_warp(
    warp: Float[Array, " N"], window: int = 5, max_ratio: float | None = 1.5, cyclic: bool = False
) -> Float[Array, " N"]:
    """A DTW warp made smooth and strictly increasing: a centred moving average over
    ``window`` frames (ends point-reflected, so their slopes are kept), plus a ramp of
    1e-3 frames per frame, rescaled to the original end points. Staircase warps otherwise
    have zero slopes (``dT/dC`` infinite in eq. 1). ``max_ratio`` (default 1.5; ``None``
    turns it off) bounds every slope to ``[mean / max_ratio, mean · max_ratio]`` with
    ``mean`` the end-to-end slope (a Sakoe–Chiba slope constraint), then rescales to the
    end points. ``cyclic=True`` (whole gait cycles) smooths across the seam with the
    increments of the other end, so the slope is continuous when a cycle wraps."""
    w = np.asarray(warp, np.float64)
    if w.ndim != 1:
        raise FxspaceError(f"warp must be a 1-D array of frames, got shape {w.shape}")
    if window < 1 or (max_ratio is not None and max_ratio < 1):
        raise FxspaceError(
            f"window must be >= 1 and max_ratio >= 1 (or None); got {window}, {max_ratio}"
        )
    n = w.size
    if n < 3:
        return w
    k = max(1, min(window, n - 1) // 2)
    # point-reflected ends keep the end slopes (a constant pad would flatten them, and a
    # flat warp makes eq. 1's dT/dC, hence the clock, jump at the start of a cycle)
    if cyclic:  # a gait cycle: the increments continue across the seam (periodic)
        pad = np.concatenate([w[0] - (w[-1] - w[-k - 1 : -1]), w, w[-1] + (w[1 : k + 1] - w[0])])
    else:
        pad = np.concatenate([2 * w[0] - w[k:0:-1], w, 2 * w[-1] - w[-2 : -k - 2 : -1]])
    s = np.convolve(pad, np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
    s = np.maximum.accumulate(s) + 1e-3 * np.arange(n)
    s = w[0] + (s - s[0]) * (w[-1] - w[0]) / max(s[-1] - s[0], 1e-12)
    if max_ratio is not None and (w[-1] - w[0]) / (n - 1) > 0:  # (a denormal span: no constraint)
        # slope constraint (Sakoe & Chiba): local tempo within max_ratio of the mean, so
        # the ill-conditioned ends of a DTW path do not make eq. 1's clock race or stall
        mean = (w[-1] - w[0]) / (n - 1)
        d = np.clip(np.diff(s), mean / max_ratio, mean * max_ratio)
        s = w[0] + np.concatenate([[0.0], np.cumsum(d)]) * (w[-1] - w[0]) / d.sum()
    return s


class RegistrationResult(NamedTuple):
    """Warps of every example against the reference (`register_examples`): ``warps``
    ``(E, N)``; ``result`` a `RESULTS` member (``nonfinite_input`` when a feature holds
    NaN/inf: then the warps are NaN, never a plausible registration); ``num_steps`` the
    DTW anti-diagonals swept per example; ``stats`` ``{"max_steps", "path_length"}``."""

    warps: Float[Array, "E N"]
    result: Any
    num_steps: Any
    stats: dict

    @property
    def converged(self):
        return is_successful(self.result)


def _check_features(features) -> None:
    if not isinstance(features, list | tuple) or not features:
        raise FxspaceError(
            f"features must be a non-empty list of (T_i, d) arrays, got {type(features).__name__}"
        )
    for i, f in enumerate(features):
        if isinstance(f, str | bytes) or np.ndim(f) != 2 or np.shape(f)[0] < 1:
            raise FxspaceError(f"features[{i}] must be a (T_i, d) array, got {f!r:.60}")
        # the dtype without copying an array off its device
        dt = np.dtype(f.dtype) if hasattr(f, "dtype") else np.asarray(f).dtype
        if dt.kind not in "fiu":
            raise FxspaceError(f"features[{i}] must be numeric, got dtype {dt}")
    d = {np.shape(f)[1] for f in features}
    if len(d) != 1:
        raise FxspaceError(f"features must share their feature size d, got {sorted(d)}")


@checked
def register_examples(
    features: list, smooth: int = 5, cyclic: bool = False, *, throw: bool = False
) -> RegistrationResult:
    """`register_dtw` with its result record (issue 18's vocabulary); ``throw=True``
    raises `FxspaceError` when a feature holds NaN/inf."""
    _check_features(features)
    lens = [int(np.shape(f)[0]) for f in features]
    T = max(lens)
    F = np.stack([np.concatenate([f, np.repeat(f[-1:], T - len(f), 0)]) for f in features])
    res = _register(jnp.asarray(F[0]), jnp.asarray(F), jnp.asarray(lens), lens[0])
    bad = np.asarray(result_code(res.result)) != member_code(RESULTS.successful)
    warps = np.stack([smooth_warp(w, smooth, cyclic=cyclic) if not b else np.full(len(w), np.nan)
                      for w, b in zip(np.asarray(res.warps), bad, strict=True)])  # fmt: skip
    result = result_from_flags(converged=True, nonfinite_input=bool(bad.any()))
    out = RegistrationResult(warps, result, res.num_steps, res.stats)
    return check_result(result, throw, "register_dtw", out)


@checked
def register_dtw(
    features: list, smooth: int = 5, cyclic: bool = False, *, throw: bool = False
) -> Float[Array, "E N"]:
    """Warps ``C_i`` of every example against the first one (the reference ``M_1``, as in the
    paper): DTW of each clip's features ``(T_i, d)`` to ``features[0]``, the matched frames
    averaged per reference frame (`warp_from_path`), smoothed (`smooth_warp`).
    One compiled batched DTW for all examples. Returns ``(E, N)`` with ``N = len(features[0])``.
    """
    return register_examples(features, smooth, cyclic, throw=throw).warps


class _Registered(NamedTuple):
    warps: Any
    result: Any
    num_steps: Any
    stats: dict


@partial(jax.jit, static_argnums=3)
def _register(ref, F, lens, n_ref: int):
    res = dtw_batch(ref, F, True, jnp.full(lens.shape, n_ref), lens)
    warps = jax.vmap(lambda p: warp_from_path(p, n_ref))(res.path)
    return _Registered(warps, res.result, res.num_steps, res.stats)


@checked
def alignment_curve(
    lower_features: Float[Array, "N d"],
    upper_features: Float[Array, "M d"],
    smooth: int = 5,
    cyclic: bool = False,
) -> Float[Array, " N"]:
    """``λ``: lower reference frame ↦ upper reference frame, by DTW of the two reference clips'
    (lower-body) features; smoothed and strictly increasing (`smooth_warp`)."""
    path = dtw(jnp.asarray(lower_features), jnp.asarray(upper_features)).path
    w = np.asarray(warp_from_path(path, int(np.shape(lower_features)[0])))
    return smooth_warp(w, smooth, cyclic=cyclic)


@checked
def drop_root(motion: Motion):
    """Remove a root joint that only carries its single child (e.g. the Bandai Namco BVH's
    ``joint_Root``): the child becomes the root, with the old root's rotation composed into
    its own and its world position as the root translation. Forward kinematics is unchanged
    for every remaining joint."""
    if sum(1 for p in motion.parents if p == 0) != 1 or motion.parents[1] != 0:
        raise ValueError("drop_root needs a root whose only child is joint 1")
    rot = np.asarray(motion.rotations)
    off = np.asarray(motion.offsets)
    X = fk_arrays(motion.parents, off, np.asarray(motion.root_translation), rot)[0]
    q1 = np.asarray(quat_mul(rot[:, 0], rot[:, 1]))
    rot = np.concatenate([q1[:, None], rot[:, 2:]], axis=1)
    offsets = off[1:].copy()
    return dataclasses.replace(
        motion,
        names=motion.names[1:],
        parents=tuple(max(p - 1, -1) for p in motion.parents[1:]),
        offsets=offsets,
        root_translation=np.asarray(X[:, 1]) - offsets[0],
        rotations=rot,
        channels=motion.channels[1:],
    )


@checked
def gait_window(motion: Motion, foot: str, n_cycles: int = 2, skip: int = 1, shift: int = 0):
    """The frames of ``n_cycles`` full gait cycles, from one touch-down of ``foot`` to the
    ``n_cycles``-th next one, after skipping the first ``skip`` touch-downs (the start of a
    walk). Touch-downs are local minima of the foot's height that lie within 3 cm of the
    clip's lowest foot height, at least 8 frames apart. ``shift`` moves both ends by that
    many frames (e.g. to mid-stance, where the foot is still: a cycle that wraps there
    has no visible seam). Raises ``ValueError`` when the clip holds too few cycles."""
    X = fk_arrays(
        motion.parents,
        np.asarray(motion.offsets),
        np.asarray(motion.root_translation),
        np.asarray(motion.rotations),
    )[0]
    h = np.asarray(X[:, motion.index(foot), 1])
    low = h.min() + 0.03
    down = [
        t
        for t in range(1, len(h) - 1)
        if h[t] <= h[t - 1] and h[t] < h[t + 1] and h[t] < low and h[t - 1] >= h[t]
    ]
    # keep the first frame of each contact phase: a touch-down follows a swing (h >= low)
    starts = [t for t in range(1, len(h)) if h[t] < low <= h[t - 1]]
    starts = starts or down
    sel = starts[skip : skip + n_cycles + 1]
    if len(sel) < n_cycles + 1:
        raise ValueError(
            f"gait_window: {len(starts)} touch-downs of {foot!r}, need {skip + n_cycles + 1}"
        )
    a, b = sel[0] + shift, sel[-1] + shift
    if a < 0 or b >= len(h):
        raise ValueError(f"gait_window: shift {shift} moves the window outside the clip")
    return motion.frames(slice(a, b + 1))
