"""Argument checks of the scripted session (`run_session`), before anything is allocated."""

from __future__ import annotations

from typing import Any

import numpy as np

from fxspace._validate import check_memory, check_scalar
from fxspace.errors import FxspaceError


def check_session_args(schedule: Any, seconds: Any, fps: float, n_joints: int) -> list:
    """``schedule`` as a list of ``(time_s, dict)`` pairs, after checking that ``seconds``
    lasts at least one frame at ``fps`` and that the session's arrays fit in memory
    (estimated first; the refusal names the GiB). Raises `FxspaceError` naming the
    argument and the fix."""
    seconds = check_scalar(seconds, "seconds", low=0.0, low_open=True)
    if seconds * fps < 0.5:
        raise FxspaceError(
            f"seconds={seconds:g} is shorter than one frame at {fps:g} fps; give at least "
            f"{1.0 / fps:.3g} s"
        )
    frames = round(seconds * fps)
    # world positions, local rotations and translations (float64, a few copies) per frame
    per_frame = 8 * (n_joints * (3 + 3 + 9) + 16) * 4
    check_memory(
        float(frames) * per_frame,
        f"a session of {seconds:g} s ({frames} frames of {n_joints} joints)",
        "shorten seconds or play it in pieces",
    )
    if schedule is None or isinstance(schedule, str | bytes | dict):
        raise FxspaceError(
            f"schedule must be a list of (time_s, {{parameter: value}}) pairs, got {schedule!r}"
        )
    try:
        items = list(schedule)
    except TypeError:
        raise FxspaceError(
            f"schedule must be a list of (time_s, {{parameter: value}}) pairs, got {schedule!r}"
        ) from None
    out = []
    for i, item in enumerate(items):
        if (
            isinstance(item, str | bytes | dict)
            or np.ndim(item) != 1
            and not isinstance(item, tuple | list)
        ):
            raise FxspaceError(
                f"schedule[{i}] must be a (time_s, {{parameter: value}}) pair, got {item!r}"
            )
        if not isinstance(item, tuple | list) or len(item) != 2:
            raise FxspaceError(
                f"schedule[{i}] must be a (time_s, {{parameter: value}}) pair, got {item!r}"
            )
        t, change = item
        t = check_scalar(t, f"schedule[{i}] time (seconds, a number)", low=0.0)
        if not isinstance(change, dict):
            raise FxspaceError(
                f"schedule[{i}] must pair its time with a dict {{parameter: value}}, got {change!r}"
            )
        out.append((t, change))
    return out
