"""Playback of a navigated frame sequence at a chosen frame rate (seed paper §5).

The final route is a sequence of captured frames; playback resamples it to ``fps``:
the time of each path step is proportional to its length in the 2-D expression space
(``by="arclength"``, the cross moves at constant speed) or constant (``by="frame"``), and
the marker positions and the 2-D cross are linearly interpolated between the two path
frames that bracket each output instant. Frames can be rigidly aligned (Kabsch) to the
first path frame so that head motion from different takes does not jump.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, NamedTuple

import numpy as np

from fxspace._validate import as_float_array, check_choice, check_memory, check_scalar
from fxspace.errors import FxspaceError
from fxspace.rigid import fit_similarity

__all__ = ["Playback", "playback", "rigid_align"]


class Playback(NamedTuple):
    """A resampled route: ``times`` (K,) s, ``xy`` (K, 2) cross positions, ``positions``
    (K, M, 3) markers, ``frame`` (K,) nearest captured frame, ``fps``."""

    times: np.ndarray
    xy: np.ndarray
    positions: np.ndarray
    frame: np.ndarray
    fps: float


def rigid_align(positions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Rotate and translate every frame of ``positions`` (T, M, 3) onto ``reference``
    (M, 3) in the least-squares sense (`fxspace.rigid.fit_similarity` with
    ``scale=False``: Kabsch, never a reflection); a frame with a NaN marker stays NaN."""
    P = as_float_array(positions, "positions", shape=(None, None, 3), finite="nan", xp="numpy")
    P = P.astype(np.float64)
    R0 = as_float_array(reference, "reference", shape=(P.shape[1], 3), xp="numpy")
    R0 = R0.astype(np.float64)
    missing = ~np.isfinite(P).all(axis=(1, 2))  # a frame with a NaN marker stays NaN
    if missing.any():
        filled = rigid_align(np.where(missing[:, None, None], R0[None], P), R0)
        return np.where(missing[:, None, None], np.nan, filled)
    R, _, t = fit_similarity(P, np.broadcast_to(R0, P.shape), scale=False)
    return np.einsum("tij,tmj->tmi", R, P) + t[:, None]


def playback(
    frames: Sequence[int],
    embedding: np.ndarray,
    positions: np.ndarray,
    *,
    fps: float = 30.0,
    rate: float = 60.0,
    duration: float | None = None,
    by: Literal["arclength", "frame"] = "arclength",
    align: bool = True,
) -> Playback:
    """Resample the frame sequence ``frames`` to ``fps``.

    **Arguments:**

    - `frames`: the route's frames (e.g. ``Route.frames`` at the finest level).
    - `embedding`: (T, 2) expression-space coordinates; `positions`: (T, M, 3) markers.
    - `fps`: output frame rate; `rate`: capture rate, used for the default duration
      ``len(frames) / rate`` seconds (each captured frame shown once on average).
    - `duration`: total length in seconds (overrides the default).
    - `by`: ``"arclength"`` (constant speed along the 2-D path) or ``"frame"``.
    - `align`: rigidly align every frame to the first path frame.
    """
    fa = np.asarray(frames)
    if fa.ndim != 1 or len(fa) < 1:
        raise FxspaceError("frames must be a non-empty 1-D sequence of frame indices")
    if fa.dtype.kind not in "iu":
        if fa.dtype.kind != "f" or not np.all(np.isfinite(fa)) or np.any(fa != np.round(fa)):
            raise FxspaceError(f"frames must be integer frame indices, got {fa.dtype} values")
    f = fa.astype(np.int64)
    fps = check_scalar(fps, "fps", low=0.0, low_open=True)
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    emb = np.asarray(as_float_array(embedding, "embedding", ndim=2, xp="numpy"), np.float64)
    pos = np.asarray(as_float_array(positions, "positions", ndim=3, xp="numpy"), np.float64)
    if pos.shape[2] != 3 or len(pos) != len(emb):
        raise FxspaceError(
            f"positions must be (T, M, 3) with T = {len(emb)} frames, got {pos.shape}"
        )
    if f.min() < 0 or f.max() >= len(emb):
        raise FxspaceError(
            f"frames must lie in [0, {len(emb) - 1}] (the embedding's frames); got "
            f"{int(f.min())} … {int(f.max())}"
        )
    check_choice(by, "by", ("arclength", "frame"))
    if duration is None:
        duration = len(f) / rate
    duration = check_scalar(duration, "duration", low=0.0, low_open=True)
    check_memory(  # estimated before anything is allocated
        (duration * fps + 1) * 8 * (3 + int(np.prod(np.shape(positions)[1:]) or 1)),
        f"a playback of {duration:g} s at {fps:g} fps",
        "shorten duration or lower fps",
    )
    xy = emb[f]
    P = pos[f]
    if align:
        P = rigid_align(P, P[0])
    if len(f) == 1:
        K = max(1, int(round(duration * fps)) + 1)
        t = np.arange(K) / fps
        return Playback(t, np.repeat(xy, K, 0), np.repeat(P, K, 0), np.repeat(f, K), float(fps))
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1) if by == "arclength" else np.ones(len(f) - 1)
    if not np.any(seg > 0):
        seg = np.ones(len(f) - 1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    s = s / s[-1] * duration  # time at each path frame
    K = max(2, int(round(duration * fps)) + 1)
    t = np.arange(K) / fps
    t = np.minimum(t, duration)
    i = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(f) - 2)
    span = np.where(s[i + 1] > s[i], s[i + 1] - s[i], 1.0)
    a = np.clip((t - s[i]) / span, 0.0, 1.0)
    out_xy = (1 - a)[:, None] * xy[i] + a[:, None] * xy[i + 1]
    out_p = (1 - a)[:, None, None] * P[i] + a[:, None, None] * P[i + 1]
    nearest = np.where(a < 0.5, f[i], f[i + 1])
    return Playback(t, out_xy, out_p, nearest, float(fps))
