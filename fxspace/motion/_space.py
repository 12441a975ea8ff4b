"""Building parameter spaces from example clips: padding/stacking, key times, windows."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_int, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.motion._blend import ExampleSet

if TYPE_CHECKING:
    from fxspace.motion._types import Motion

__all__ = ["stack_examples", "find_key_times", "extract_window"]


@checked
def stack_examples(rotations: list, roots: list, warps: Float[Array, "E N"]) -> ExampleSet:
    """Pad clips of different lengths (repeating the last frame) into an `ExampleSet`."""
    if len(rotations) != len(roots) or len(rotations) != warps.shape[0]:
        raise ValueError(
            f"rotations ({len(rotations)}), roots ({len(roots)}) and warps "
            f"({warps.shape[0]}) must describe the same number of examples"
        )
    lengths = [int(np.shape(r)[0]) for r in rotations]
    T = max(lengths)

    def pad(x):
        x = np.asarray(x)
        return np.concatenate([x, np.repeat(x[-1:], T - x.shape[0], axis=0)], axis=0)

    return ExampleSet(
        rotations=jnp.asarray(np.stack([pad(r) for r in rotations])),
        root=jnp.asarray(np.stack([pad(r) for r in roots])),
        lengths=jnp.asarray(lengths, dtype=jnp.int32),
        warps=jnp.asarray(warps),
    )


def find_key_times(
    signal, min_separation: int, max_keys: int, margin: int = 0, rel_height: float = 0.7
) -> list[int]:
    """Frames of the strongest local maxima of a 1-D ``signal`` (e.g. hand reach, foot
    height): greedy, highest first, at least ``min_separation`` frames apart, at least
    ``margin`` frames from either end, and at least ``rel_height`` of the way from the
    signal's median to its maximum. Sorted by time."""
    s = as_float_array(signal, "signal", xp="numpy").astype(np.float64)
    if s.ndim != 1 or s.size < 3:
        raise FxspaceError(f"signal must be a 1-D array of at least 3 frames, got shape {s.shape}")
    min_separation = check_int(min_separation, "min_separation", low=0)
    max_keys = check_int(max_keys, "max_keys", low=0)
    margin = check_int(margin, "margin", low=0)
    rel_height = check_scalar(rel_height, "rel_height", low=0.0, high=1.0)
    lo, hi = np.median(s), s.max()
    thr = lo + rel_height * (hi - lo)
    peak = np.zeros(s.size, bool)
    peak[1:-1] = (s[1:-1] >= s[:-2]) & (s[1:-1] >= s[2:]) & (s[1:-1] >= thr)
    cands = [i for i in np.argsort(-s) if peak[i] and margin <= i < s.size - margin]
    keys: list[int] = []
    for i in cands:
        if all(abs(i - k) >= min_separation for k in keys):
            keys.append(int(i))
        if len(keys) == max_keys:
            break
    return sorted(keys)


@checked
def extract_window(motion: Motion, start: int, stop: int):
    """Frames ``start:stop`` of a Motion (clamped to the clip)."""
    start = max(0, start)
    stop = min(motion.num_frames, stop)
    if stop - start < 2:
        raise ValueError(f"window [{start}, {stop}) holds fewer than 2 frames")
    return motion.frames(slice(start, stop))
