"""The figure of ``fxspace report``: one metric against the swept key(s) of a sweep."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

__all__ = ["plot_report_metric"]


def _is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def plot_report_metric(
    x: Sequence,
    y: Sequence[float],
    *,
    x_label: str,
    y_label: str,
    group: Sequence[str] | None = None,
    group_label: str = "",
    title: str = "",
    best: int | Sequence[int] | None = None,
    better: str | None = None,
) -> Figure:
    """One metric of a sweep (``y``, one value per run) against a swept key (``x``).

    ``group``: for each run, the values of the other swept keys as one label — one line
    per group, named in the legend (``group_label`` its title). Integer keys get integer
    ticks (at the swept values when there are at most 12), float keys a tick at each
    swept value when there are at most 8, text keys one category each; an integer metric
    gets integer ticks. ``x_label`` / ``y_label``: the axes in words with their units.

    ``best``: the index (or indices, for a tie) of the best run, starred — only for a
    metric with a known direction, ``better`` = ``"higher"`` or ``"lower"`` (named in the
    legend); a metric with none gets no star (``best`` must then be None).
    """
    xs, int_y = list(x), all(_is_int(v) for v in y)
    ys = np.asarray(y, float)
    if len(xs) != len(ys):
        raise ValueError(f"x has {len(xs)} values and y {len(ys)}; pass one of each per run")
    if best is not None and better not in ("higher", "lower"):
        raise ValueError(f"best needs better='higher' or 'lower' (the metric's direction), "
                         f"got {better!r}")  # fmt: skip
    groups = [""] * len(xs) if group is None else [str(g) for g in group]
    numeric = all(isinstance(v, int | float | np.number) and not isinstance(v, bool)
                  for v in xs)  # fmt: skip
    cats = [] if numeric else sorted({str(v) for v in xs})
    pos = [float(v) if numeric else float(cats.index(str(v))) for v in xs]

    fig, ax = plt.subplots(figsize=(6.0, 4.0), layout="constrained")
    names = sorted(set(groups), key=lambda g: (len(g), g))
    for i, g in enumerate(names):
        idx = sorted((j for j in range(len(xs)) if groups[j] == g), key=lambda j: pos[j])
        ax.plot([pos[j] for j in idx], ys[idx], "o-", color=f"C{i % 10}", lw=1.8, ms=6,
                label=g or None, zorder=3)  # fmt: skip
    if best is not None:
        bi = [best] if isinstance(best, int | np.integer) else list(best)
        ax.plot([pos[i] for i in bi], ys[bi], "*", ms=18, color="gold", mec="black", mew=0.8,
                zorder=5, label=f"best ({better} is better)")  # fmt: skip

    distinct = sorted(set(pos))
    if not numeric:
        ax.set_xticks(range(len(cats)), cats, rotation=30 if len(cats) > 4 else 0,
                      ha="right" if len(cats) > 4 else "center")  # fmt: skip
        ax.set_xlim(-0.5, len(cats) - 0.5)
    elif all(_is_int(v) for v in xs):
        if len(distinct) <= 12:
            ax.set_xticks(distinct, [str(int(v)) for v in distinct])
        else:
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    elif len(distinct) <= 8:
        ax.set_xticks(distinct, [f"{v:.4g}" for v in distinct])
    if len(distinct) > 1:
        pad = 0.08 * (distinct[-1] - distinct[0])
        ax.set_xlim(distinct[0] - pad, distinct[-1] + pad)
    if int_y:
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    if title:
        ax.set_title(title, fontsize=10, family="monospace")
    ax.grid(True, alpha=0.3)
    if any(names) or best is not None:
        ax.legend(title=group_label or None, fontsize=8, title_fontsize=8, loc="best",
                  framealpha=0.85)  # fmt: skip
    return fig
