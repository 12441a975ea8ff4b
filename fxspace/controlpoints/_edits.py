"""Free, key-framed edits anchored on the face (Hirose & Higuchi §1: the animator moves
control points freely at any frame and the surrounding vertices follow).

An edit key is ``FaceKey(frame, vertex, offset)``: at scene ``frame`` the place on the face
around ``vertex`` (its *anchor*) is displaced by the 3-D ``offset``. A key does not belong
to a segment: it applies at any frame, segment boundaries included, and is carried across
boundaries through the control points of whichever segment holds each frame.

**Offsets in time.** The keys of one anchor (the last key at a frame wins) are joined by
cubic Hermite steps with zero slopes (smoothstep ``h(s) = 3s² − 2s³``: C¹, no overshoot),
so two keys with the same offset *hold* it between them, across boundaries too. Before
the first key the offset rises from zero at the last segment boundary before it; after
the last key it falls to zero at the first boundary after it (a single key inside a
segment therefore behaves as in the paper's per-segment editing).

**Region in space.** At a frame of segment ``s`` the anchor's region is the blend-weight
column of the control point that holds the anchor vertex in segment ``s``
(``φ_i = w^s_{i,k}``, ``k = argmax_k w^s_{anchor,k}``), so vertex ``i`` moves by
``φ_i(t) o(t)`` and the anchor itself by the full offset. Around each boundary the two
segments' regions are cross-faded over ``blend`` frames on each side (smoothstep), so a
held offset does not jump when the regions differ.

The edited scene is ``x̃(t) = x̂(t) + Σ_anchors φ(t) o(t)`` (`edited_vertices`). Keys are
data: the list is the edit history (undo = drop the last key), saved as JSON in the run
folder (`save_edits` / `load_edits`). Files of the earlier per-segment form
(``EditKey(segment, control, frame, offset)``, version 1) still load and are converted by
`convert_keys` (the anchor is the control point's most central vertex); `apply_edits`
still replays such keys on a `SceneModel` as before.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from fxspace._validate import check_int, checked
from fxspace.controlpoints._model import ControlPointModel, _control_residuals
from fxspace.controlpoints._scene import SceneModel, reconstruct_scene, segment_of_frame
from fxspace.controlpoints._segment import check_boundaries
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.runs import write_json_atomic

__all__ = [
    "EditKey",
    "FaceKey",
    "keyed_offsets",
    "edit_control_keys",
    "apply_edits",
    "effective_keys",
    "control_positions",
    "anchor_vertex",
    "convert_keys",
    "check_face_keys",
    "anchor_offsets",
    "segment_blend",
    "edit_displacements",
    "edited_vertices",
    "edited_control_positions",
    "save_edits",
    "load_edits",
]

BLEND_FRAMES = 4


class EditKey(NamedTuple):
    """A per-segment key (the earlier form, kept for old ``edits.json`` files): control
    point ``control`` of ``segment`` moved by ``offset`` at scene ``frame``."""

    segment: int
    control: int
    frame: int
    offset: tuple[float, float, float]


class FaceKey(NamedTuple):
    """A key anchored on the face: at scene ``frame`` the region around ``vertex`` moves
    by ``offset`` (scene units), whatever segment holds the frame."""

    frame: int
    vertex: int
    offset: tuple[float, float, float]


@checked
def keyed_offsets(
    n_frames: int, frames: Int[ArrayLike, " K"], offsets: Float[ArrayLike, "K 3"]
) -> Float[Array, "T 3"]:
    """Offsets at every local frame ``0 … n_frames−1`` from keys at in-between ``frames``
    (zero at both ends; smoothstep between consecutive keys). jit-able for fixed K."""
    n_frames = check_int(n_frames, "n_frames", low=2)
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


@checked
def edit_control_keys(
    model: ControlPointModel,
    index: int,
    frames: Sequence[int],
    offsets: Float[ArrayLike, "K 3"],
) -> ControlPointModel:
    """Move control point ``index`` of one segment model by key-framed ``offsets`` at local
    in-between ``frames`` (1 … T−2), interpolated by `keyed_offsets`."""
    c, T = model.controls.shape[:2]
    if not 0 <= int(index) < c:
        raise FxspaceError(f"index must be in [0, {c}) (control points); got {index}")
    fr = [int(x) for x in frames]
    if any(not 0 < x < T - 1 for x in fr):
        raise FxspaceError(
            f"key frames must be in-between frames 1 … {T - 2} (the ends are the stored key "
            f"frames); got {fr}"
        )
    if not isinstance(offsets, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(offsets))):
        raise FxspaceError("offsets must be finite (no NaN/inf); give a number for every axis")
    off = keyed_offsets(T, fr, jnp.asarray(offsets, model.controls.dtype))
    return model._replace(controls=model.controls.at[int(index)].add(off))


@checked
def effective_keys(keys: Sequence[EditKey]) -> dict[tuple[int, int], list[EditKey]]:
    """Per-segment keys grouped by (segment, control), the last key at each frame winning."""
    keys = _check_keys(keys, (EditKey,))
    last: dict[tuple[int, int, int], EditKey] = {}
    for k in keys:
        last[(int(k.segment), int(k.control), int(k.frame))] = k
    out: dict[tuple[int, int], list[EditKey]] = {}
    for (s, c, _), k in last.items():
        out.setdefault((s, c), []).append(k)
    return {sc: sorted(v, key=lambda k: k.frame) for sc, v in out.items()}


def _check_keys(keys, kinds: tuple) -> list:
    names = " or ".join(k.__name__ for k in kinds)
    if isinstance(keys, str | bytes) or not hasattr(keys, "__iter__"):
        raise FxspaceError(f"keys must be a sequence of {names}s, got {type(keys).__name__}")
    keys = list(keys)
    for i, k in enumerate(keys):
        if not isinstance(k, kinds):
            raise FxspaceError(f"keys[{i}] must be an {names}, got {type(k).__name__}")
    return keys


def _check_offset(offset, where: str) -> tuple[float, float, float]:
    try:
        o = np.asarray(offset, np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise FxspaceError(f"{where}: offset must be 3 numbers; got {offset!r}") from e
    if o.shape != (3,):
        raise FxspaceError(f"{where}: offset must be 3 numbers; got {o.size}")
    if not np.all(np.isfinite(o)):
        raise FxspaceError(f"{where}: offset must be finite (no NaN/inf); got {o.tolist()}")
    return (float(o[0]), float(o[1]), float(o[2]))


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
    _check_offset(k.offset, f"edit key at frame {k.frame}")


@checked
def apply_edits(scene: SceneModel, keys: Sequence[EditKey]) -> SceneModel:
    """Replay per-segment ``keys`` (`EditKey`) on ``scene``'s control trajectories (zero at
    every segment's ends). For keys anchored on the face use `edited_vertices`."""
    if any(isinstance(k, FaceKey) for k in keys):
        raise FxspaceError(
            "apply_edits replays per-segment EditKeys; FaceKeys apply at any frame: use "
            "fx.edited_vertices(scene, keys)"
        )
    for k in keys:
        _check_key(scene, k)
    segs = list(scene.segments)
    for (s, c), ks in effective_keys(keys).items():
        a = int(scene.boundaries[s])
        segs[s] = edit_control_keys(
            segs[s], c, [k.frame - a for k in ks], np.asarray([k.offset for k in ks], float)
        )
    return scene._replace(segments=tuple(segs))


@checked
def control_positions(scene: SceneModel, frame: int) -> tuple[int, Float[np.ndarray, "c 3"]]:
    """``(segment, (c, 3))``: the control points (cluster-centre coordinates ``C_k(t)``) at
    scene ``frame``, in the segment holding it (a boundary frame: the segment it starts)."""
    s, t = segment_of_frame(scene.boundaries, frame)
    return s, np.asarray(scene.segments[s].controls[:, t])


@checked
def anchor_vertex(scene: SceneModel, segment: int, control: int, frame: int | None = None) -> int:
    """The vertex that stands for control point ``control`` of ``segment``: among the
    vertices it holds most strongly, the one nearest the control point at ``frame``
    (default: the segment's middle frame)."""
    b = scene.boundaries
    if not 0 <= int(segment) < len(b) - 1:
        raise FxspaceError(f"segment must be in [0, {len(b) - 2}]; got {segment}")
    m = scene.segments[int(segment)]
    c, T = m.controls.shape[:2]
    if not 0 <= int(control) < c:
        raise FxspaceError(f"control must be in [0, {c}) in segment {segment}; got {control}")
    t = (T - 1) // 2 if frame is None else int(np.clip(int(frame) - int(b[segment]), 0, T - 1))
    w = np.asarray(m.weights[:, int(control)])
    cand = np.flatnonzero(w >= w.max() - 1e-9)
    # the model's own frame t (linear part + this control's non-linear part), no other data
    s = t / (T - 1)
    P = (1 - s) * np.asarray(m.first)[cand] + s * np.asarray(m.last)[cand]
    R = np.asarray(_control_residuals(m.controls))[int(control), t]
    d = np.linalg.norm(P + R - np.asarray(m.controls[int(control), t]), axis=1)
    return int(cand[int(np.argmin(d))])


@checked
def convert_keys(scene: SceneModel, keys: Sequence[EditKey | FaceKey]) -> list[FaceKey]:
    """Per-segment keys (an old ``edits.json``) as keys on the face: each ``(segment,
    control)`` becomes its `anchor_vertex`; `FaceKey`s pass through."""
    out: list[FaceKey] = []
    anchors: dict[tuple[int, int], int] = {}
    for k in keys:
        if isinstance(k, FaceKey):
            out.append(k)
            continue
        _check_key(scene, k)
        sc = (int(k.segment), int(k.control))
        if sc not in anchors:
            anchors[sc] = anchor_vertex(scene, *sc)
        out.append(FaceKey(int(k.frame), anchors[sc], _check_offset(k.offset, "edit key")))
    return out


@checked
def check_face_keys(scene: SceneModel, keys: Sequence[FaceKey]) -> list[FaceKey]:
    """Validate keys against ``scene`` (frame in the scene, vertex on the face, finite
    offset); returns them as `FaceKey`s."""
    T, N = scene.n_frames, scene.n_vertices
    out = []
    for k in keys:
        if not isinstance(k, FaceKey):
            raise FxspaceError(f"expected FaceKey(frame, vertex, offset); got {k!r}")
        f, v = int(k.frame), int(k.vertex)
        if f != k.frame or not 0 <= f < T:
            raise FxspaceError(f"edit key frame must be an integer in [0, {T - 1}]; got {k.frame}")
        if v != k.vertex or not 0 <= v < N:
            raise FxspaceError(f"edit key vertex must be an integer in [0, {N}); got {k.vertex}")
        out.append(FaceKey(f, v, _check_offset(k.offset, f"edit key at frame {f}")))
    return out


def _smooth_path(knots: list[int], vals: list[np.ndarray], n_frames: int) -> np.ndarray:
    """Values at every frame: smoothstep between consecutive knots, zero outside."""
    out = np.zeros((n_frames, 3))
    if len(knots) == 1:
        out[knots[0]] = vals[0]
        return out
    for i in range(len(knots) - 1):
        a, e = knots[i], knots[i + 1]
        s = (np.arange(a, e + 1) - a) / (e - a)
        out[a : e + 1] = vals[i] + (s * s * (3 - 2 * s))[:, None] * (vals[i + 1] - vals[i])
    return out


@checked
def anchor_offsets(
    keys: Sequence[FaceKey], boundaries: Int[ArrayLike, " s1"]
) -> dict[int, np.ndarray]:
    """``{vertex: (T, 3) offsets}`` of every anchor (see the module docstring)."""
    b = np.asarray(boundaries, np.int64)
    T = int(b[-1]) + 1
    last: dict[tuple[int, int], np.ndarray] = {}
    for k in keys:
        last[(int(k.vertex), int(k.frame))] = np.asarray(k.offset, np.float64)
    by: dict[int, list[tuple[int, np.ndarray]]] = {}
    for (v, f), o in last.items():
        by.setdefault(v, []).append((f, o))
    out = {}
    for v, items in by.items():
        items.sort(key=lambda x: x[0])
        knots, vals = [f for f, _ in items], [o for _, o in items]
        lo, hi = b[b < knots[0]], b[b > knots[-1]]
        if len(lo):
            knots, vals = [int(lo[-1]), *knots], [np.zeros(3), *vals]
        if len(hi):
            knots, vals = [*knots, int(hi[0])], [*vals, np.zeros(3)]
        out[v] = _smooth_path(knots, vals, T)
    return out


def segment_blend(boundaries: Int[ArrayLike, " s1"], blend: int = BLEND_FRAMES) -> np.ndarray:
    """``(T, s)`` how much each segment's control points hold each frame: one-hot in the
    segment holding the frame, cross-faded (smoothstep) over ``blend`` frames on each side
    of every interior boundary (``0.5``/``0.5`` at the boundary frame itself)."""
    b = check_boundaries(boundaries)
    blend = check_int(blend, "blend", low=0)
    T, S = int(b[-1]) + 1, len(b) - 1
    A = np.zeros((T, S))
    for t in range(T):
        A[t, segment_of_frame(b, t)[0]] = 1.0
    for j in range(1, S):
        h = max(1, min(int(blend), int(b[j] - b[j - 1]) // 2, int(b[j + 1] - b[j]) // 2))
        for t in range(int(b[j]) - h + 1, int(b[j]) + h):
            u = (t - (b[j] - h)) / (2.0 * h)
            beta = u * u * (3 - 2 * u)
            A[t] = 0.0
            A[t, j - 1], A[t, j] = 1.0 - beta, beta
    return A


def _regions(scene: SceneModel, vertex: int) -> np.ndarray:
    """``(s, N)``: in each segment, the weight column of the control holding ``vertex``."""
    cols = []
    for m in scene.segments:
        W = np.asarray(m.weights)
        cols.append(W[:, int(np.argmax(W[int(vertex)]))])
    return np.stack(cols)


@checked
def edit_displacements(
    scene: SceneModel,
    keys: Sequence[FaceKey],
    frames: Sequence[int] | None = None,
    blend: int = BLEND_FRAMES,
) -> Float[np.ndarray, "F N 3"]:
    """Displacement of every vertex at ``frames`` (default all) by the face-anchored
    ``keys``: ``Σ_anchors φ(t) o(t)`` (module docstring). O(F·N) per anchor."""
    keys = check_face_keys(scene, keys)
    T, N = scene.n_frames, scene.n_vertices
    fr = np.arange(T) if frames is None else np.asarray(frames, np.int64).reshape(-1)
    D = np.zeros((len(fr), N, 3), np.float64)
    if not keys:
        return D
    A = segment_blend(scene.boundaries, blend)[fr]  # (F, s)
    for v, path in anchor_offsets(keys, scene.boundaries).items():
        o = path[fr]
        live = np.flatnonzero(np.any(o != 0, axis=1))
        if len(live):
            phi = A[live] @ _regions(scene, v)  # (F', N)
            D[live] += phi[:, :, None] * o[live][:, None, :]
    return D


@checked
def edited_vertices(
    scene: SceneModel, keys: Sequence[FaceKey], blend: int = BLEND_FRAMES
) -> Float[np.ndarray, "T N 3"]:
    """The edited scene ``x̂(t) + Σ φ(t) o(t)``: the model (`fxspace.reconstruct_scene`)
    plus `edit_displacements`."""
    X = np.asarray(reconstruct_scene(scene), np.float64)
    return X + edit_displacements(scene, keys, blend=blend)


@checked
def edited_control_positions(
    scene: SceneModel, keys: Sequence[FaceKey], frame: int, blend: int = BLEND_FRAMES
) -> tuple[int, Float[np.ndarray, "c 3"]]:
    """``(segment, (c, 3))``: the control points at ``frame`` moved by the edits (each by
    its weighted mean vertex displacement)."""
    s, C = control_positions(scene, frame)
    D = edit_displacements(scene, keys, [frame], blend)[0]
    W = np.asarray(scene.segments[s].weights, np.float64)
    return s, np.asarray(C, np.float64) + (W.T @ D) / np.maximum(W.sum(0), 1e-12)[:, None]


def _key_dict(k: EditKey | FaceKey) -> dict:
    d = {f: int(getattr(k, f)) for f in k._fields if f != "offset"}
    return {**d, "offset": [float(v) for v in k.offset]}


@checked
def save_edits(path: str | Path, keys: Sequence[EditKey | FaceKey], **meta) -> Path:
    """Write the keys (in order: the history) as JSON, atomically; ``meta`` is stored too.
    `FaceKey`s are written as version 2, per-segment `EditKey`s as version 1."""
    p = Path(path)
    keys = _check_keys(keys, (EditKey, FaceKey))
    face = all(isinstance(k, FaceKey) for k in keys)
    if not face and any(isinstance(k, FaceKey) for k in keys):
        raise FxspaceError("keys must be all FaceKeys or all EditKeys; convert with convert_keys")
    for k in keys:
        _check_offset(k.offset, f"edit key at frame {k.frame}")
    version = 2 if face else 1
    write_json_atomic(p, {**meta, "version": version, "keys": [_key_dict(k) for k in keys]})
    return p


@checked
def load_edits(path: str | Path) -> tuple[list[EditKey | FaceKey], dict]:
    """``(keys, meta)`` from `save_edits`' JSON: `FaceKey`s (version 2) or per-segment
    `EditKey`s (version 1: convert with `convert_keys`). A damaged file raises
    `fxspace.errors.CorruptFileError` naming it."""
    p = Path(path)
    try:
        raw = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        msg = f"{p}: not a readable edits file ({e}); delete it or restore it"
        raise CorruptFileError(msg) from None
    if not isinstance(raw, dict) or not isinstance(raw.get("keys"), list):
        raise CorruptFileError(f"{p}: not an edits file (no 'keys' list)")
    keys: list[EditKey | FaceKey] = []
    for i, d in enumerate(raw["keys"]):
        try:
            if "vertex" in d:
                k = FaceKey(int(d["frame"]), int(d["vertex"]), _check_offset(d["offset"], ""))
            else:
                k = EditKey(int(d["segment"]), int(d["control"]), int(d["frame"]),
                            _check_offset(d["offset"], ""))  # fmt: skip
        except (KeyError, TypeError, ValueError) as e:
            raise CorruptFileError(f"{p}: key {i} is damaged ({e})") from None
        keys.append(k)
    meta = {k: v for k, v in raw.items() if k != "keys"}
    return keys, meta
