"""Free, key-framed edits of control points (Hirose & Higuchi §1: the animator moves each
control point freely at every frame and the region around it follows).

An edit is a list of keys ``(segment, control, frame, offset)``: at scene ``frame`` the
control point ``control`` of ``segment`` is displaced by the 3-D ``offset``. Between keys
the offset of one control point is interpolated smoothly (cubic Hermite with zero
slopes, i.e. smoothstep ``h(s) = 3s² − 2s³`` — C¹, no overshoot), and it falls to zero at
the segment's first and last frames, the stored key frames shared with the neighbouring
segments, so the stitched scene stays continuous. Vertex ``i`` follows through its blend
weights: ``x̃_i(t) = x̂_i(t) + Σ_k w_ik o_k(t)``.

Keys are data: a later key at the same (segment, control, frame) replaces an earlier one,
so the list itself is the edit history (undo = drop the last key) and it is saved as JSON
in the run folder (:func:`save_edits` / :func:`load_edits`) and replayed by
:func:`apply_edits`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from fxspace.controlpoints._model import ControlPointModel
from fxspace.controlpoints._scene import SceneModel
from fxspace.errors import FxspaceError
from fxspace.runs import write_json_atomic

__all__ = [
    "EditKey",
    "keyed_offsets",
    "edit_control_keys",
    "apply_edits",
    "effective_keys",
    "control_positions",
    "save_edits",
    "load_edits",
]


class EditKey(NamedTuple):
    """One key: control point ``control`` of ``segment`` moved by ``offset`` at scene
    ``frame`` (an in-between frame of that segment)."""

    segment: int
    control: int
    frame: int
    offset: tuple[float, float, float]


def keyed_offsets(
    n_frames: int, frames: Int[ArrayLike, " K"], offsets: Float[ArrayLike, "K 3"]
) -> Float[Array, "T 3"]:
    """Offsets at every local frame ``0 … n_frames−1`` from keys at in-between ``frames``
    (zero at both ends; smoothstep between consecutive keys). jit-able for fixed K."""
    f = jnp.asarray(frames, dtype=jnp.result_type(float))
    o = jnp.asarray(offsets)
    if o.ndim != 2 or o.shape[1] != 3 or f.shape != (o.shape[0],):
        raise FxspaceError(f"frames (K,) and offsets (K, 3) expected; got {f.shape}, {o.shape}")
    order = jnp.argsort(f)
    knots = jnp.concatenate([jnp.zeros(1, f.dtype), f[order], jnp.full(1, n_frames - 1.0)])
    vals = jnp.concatenate([jnp.zeros((1, 3), o.dtype), o[order], jnp.zeros((1, 3), o.dtype)])
    t = jnp.arange(n_frames, dtype=f.dtype)
    j = jnp.clip(jnp.searchsorted(knots, t, side="right") - 1, 0, knots.shape[0] - 2)
    span = knots[j + 1] - knots[j]
    s = jnp.clip((t - knots[j]) / jnp.where(span > 0, span, 1.0), 0.0, 1.0)
    h = s * s * (3.0 - 2.0 * s)
    return vals[j] + h[:, None].astype(o.dtype) * (vals[j + 1] - vals[j])


def edit_control_keys(
    model: ControlPointModel,
    index: int,
    frames: Sequence[int],
    offsets: Float[ArrayLike, "K 3"],
) -> ControlPointModel:
    """Move control point ``index`` of one segment model by key-framed ``offsets`` at local
    in-between ``frames`` (1 … T−2), interpolated by :func:`keyed_offsets`."""
    c, T = model.controls.shape[:2]
    if not 0 <= int(index) < c:
        raise FxspaceError(f"index must be in [0, {c}) (control points); got {index}")
    fr = [int(x) for x in frames]
    if any(not 0 < x < T - 1 for x in fr):
        raise FxspaceError(
            f"key frames must be in-between frames 1 … {T - 2} (the ends are the stored key "
            f"frames); got {fr}"
        )
    off = keyed_offsets(T, fr, jnp.asarray(offsets, model.controls.dtype))
    return model._replace(controls=model.controls.at[int(index)].add(off))


def effective_keys(keys: Sequence[EditKey]) -> dict[tuple[int, int], list[EditKey]]:
    """Keys grouped by (segment, control), the last key at each frame winning, by frame."""
    last: dict[tuple[int, int, int], EditKey] = {}
    for k in keys:
        last[(int(k.segment), int(k.control), int(k.frame))] = k
    out: dict[tuple[int, int], list[EditKey]] = {}
    for (s, c, _), k in last.items():
        out.setdefault((s, c), []).append(k)
    return {sc: sorted(v, key=lambda k: k.frame) for sc, v in out.items()}


def _check_key(scene: SceneModel, k: EditKey) -> None:
    b = scene.boundaries
    s = int(k.segment)
    if not 0 <= s < len(b) - 1:
        raise FxspaceError(f"edit key segment {s} does not exist (0 … {len(b) - 2})")
    c = scene.segments[s].controls.shape[0]
    if not 0 <= int(k.control) < c:
        raise FxspaceError(f"edit key control {k.control} of segment {s} is not in [0, {c})")
    if not int(b[s]) < int(k.frame) < int(b[s + 1]):
        raise FxspaceError(
            f"edit key frame {k.frame} is not an in-between frame of segment {s} "
            f"({int(b[s]) + 1} … {int(b[s + 1]) - 1}); boundary frames are stored key frames"
        )


def apply_edits(scene: SceneModel, keys: Sequence[EditKey]) -> SceneModel:
    """Replay ``keys`` on ``scene``: every edited control trajectory gets its interpolated
    offsets (see the module docstring). Validates every key."""
    for k in keys:
        _check_key(scene, k)
    segs = list(scene.segments)
    for (s, c), ks in effective_keys(keys).items():
        a = int(scene.boundaries[s])
        segs[s] = edit_control_keys(
            segs[s], c, [k.frame - a for k in ks], np.asarray([k.offset for k in ks], float)
        )
    return scene._replace(segments=tuple(segs))


def control_positions(scene: SceneModel, frame: int) -> tuple[int, Float[np.ndarray, "c 3"]]:
    """``(segment, (c, 3))``: the control points (cluster-centre coordinates ``C_k(t)``) at
    scene ``frame``, in the segment whose in-between frames contain it (a boundary frame:
    the segment it starts)."""
    from fxspace.controlpoints._scene import segment_of_frame

    s, t = segment_of_frame(scene.boundaries, frame)
    return s, np.asarray(scene.segments[s].controls[:, t])


def _key_dict(k: EditKey) -> dict:
    return {
        "segment": int(k.segment),
        "control": int(k.control),
        "frame": int(k.frame),
        "offset": [float(v) for v in k.offset],
    }


def save_edits(path: str | Path, keys: Sequence[EditKey], **meta) -> Path:
    """Write the keys (in order: the history) as JSON, atomically; ``meta`` is stored too
    (e.g. the model's boundaries, to refuse replaying onto another segmentation)."""
    p = Path(path)
    write_json_atomic(p, {"version": 1, **meta, "keys": [_key_dict(k) for k in keys]})
    return p


def load_edits(path: str | Path) -> tuple[list[EditKey], dict]:
    """``(keys, meta)`` from :func:`save_edits`' JSON."""
    raw = json.loads(Path(path).read_text())
    if not isinstance(raw, dict) or "keys" not in raw:
        raise FxspaceError(f"{path}: not an edits file (no 'keys')")
    keys = [
        EditKey(int(d["segment"]), int(d["control"]), int(d["frame"]),
                tuple(float(v) for v in d["offset"]))  # type: ignore[arg-type]
        for d in raw["keys"]
    ]  # fmt: skip
    meta = {k: v for k, v in raw.items() if k != "keys"}
    return keys, meta
