"""The figure of Ha & Han's Fig. 3 read off the synthesised joints: the arm swing's phase at
each stride (clocks apart, aligned as printed, aligned with the bound) and the forward
offsets of the feet and of the hands over the first seconds."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

__all__ = ["plot_arm_swing_coupling"]


def plot_arm_swing_coupling(
    phases: Sequence[tuple[str, Any]],
    swings: Sequence[tuple[str, Any, Any, Any]],
    title: str = "",
) -> Figure:
    """The upper body's arm swing against the strides (Ha & Han Fig. 3).

    **Arguments:**

    - `phases`: ``(label, coupling)`` per way the clocks ran, a coupling as
      `fxspace.motion.cycle_coupling` returns it (``lower_events``, ``upper_events``,
      ``relative_phase``, ``cycle_ratio``, ``phase_drift``): the top panel.
    - `swings`: two ``(name, t, feet, hands)``: times (s) and the forward offsets (m) of
      left foot − right foot and right hand − left hand (`fxspace.motion.swing_signal`):
      the two lower panels.
    - `title`: the figure's title.

    **Returns:** the `Figure` (three panels, one above the other).
    """
    fig, axes = plt.subplots(3, 1, figsize=(11, 8))
    ax = axes[0]
    for i, (lab, c) in enumerate(phases):
        inside = c.lower_events[(c.lower_events >= c.upper_events[0])
                                & (c.lower_events <= c.upper_events[-1])]  # fmt: skip
        ax.plot(inside[: c.relative_phase.size], c.relative_phase, f"C{i}.-",
                label=f"{lab}: ratio {c.cycle_ratio:.3f}, drift {c.phase_drift:.2f}/min")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("arm-swing phase at each stride (cycles)")
    ax.legend(fontsize=7)
    for ax, (name, t, feet, hands) in zip(axes[1:], swings, strict=True):
        ax.plot(t, feet, label="left foot − right foot")
        ax.plot(t, hands, label="right hand − left hand")
        ax.set_title(f"{name}: forward offsets, first 8 s", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("m")
        ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
