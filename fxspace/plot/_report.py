"""The figure of ``fxspace report``: one metric against the swept key(s) of a sweep."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

__all__ = ["plot_report_metric", "plot_report_grid", "plot_report_figure"]


def _is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _numeric(xs: Sequence) -> bool:
    return all(isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in xs)


def _positions(xs: Sequence) -> list[float]:
    """Where each run sits on the x axis: its value, or its category's index for text."""
    if _numeric(xs):
        return [float(v) for v in xs]
    cats = sorted({str(v) for v in xs})
    return [float(cats.index(str(v))) for v in xs]


def _x_ticks(ax, xs: Sequence, pos: list[float]) -> None:
    """Integer keys: integer ticks (at the swept values when at most 12); float keys: a
    tick at each swept value when at most 8; text keys: one category each."""
    distinct = sorted(set(pos))
    if not _numeric(xs):
        cats = sorted({str(v) for v in xs})
        ax.set_xticks(range(len(cats)), cats, rotation=30 if len(cats) > 4 else 0,
                      ha="right" if len(cats) > 4 else "center")  # fmt: skip
        ax.set_xlim(-0.5, len(cats) - 0.5)
        return
    if all(_is_int(v) for v in xs):
        if len(distinct) <= 12:
            ax.set_xticks(distinct, [str(int(v)) for v in distinct])
        else:
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    elif len(distinct) <= 8:
        ax.set_xticks(distinct, [f"{v:.4g}" for v in distinct])
    if len(distinct) > 1:
        pad = 0.08 * (distinct[-1] - distinct[0])
        ax.set_xlim(distinct[0] - pad, distinct[-1] + pad)


def _best_list(best, better) -> list[int]:
    if best is None:
        return []
    if better not in ("higher", "lower"):
        raise ValueError(f"best needs better='higher' or 'lower' (the metric's direction), "
                         f"got {better!r}")  # fmt: skip
    return [int(best)] if isinstance(best, int | np.integer) else [int(i) for i in best]


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
    bi = _best_list(best, better)
    groups = [""] * len(xs) if group is None else [str(g) for g in group]
    pos = _positions(xs)

    fig, ax = plt.subplots(figsize=(6.0, 4.0), layout="constrained")
    names = sorted(set(groups), key=lambda g: (len(g), g))
    for i, g in enumerate(names):
        idx = sorted((j for j in range(len(xs)) if groups[j] == g), key=lambda j: pos[j])
        ax.plot([pos[j] for j in idx], ys[idx], "o-", color=f"C{i % 10}", lw=1.8, ms=6,
                label=g or None, zorder=3)  # fmt: skip
    if bi:
        ax.plot([pos[i] for i in bi], ys[bi], "*", ms=18, color="gold", mec="black", mew=0.8,
                zorder=5, label=f"best ({better} is better)")  # fmt: skip

    _x_ticks(ax, xs, pos)
    if int_y:
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    if title:
        ax.set_title(title, fontsize=10, family="monospace")
    ax.grid(True, alpha=0.3)
    if any(names) or bi:
        ax.legend(title=group_label or None, fontsize=8, title_fontsize=8, loc="best",
                  framealpha=0.85)  # fmt: skip
    return fig


def plot_report_grid(
    xs: dict[str, Sequence],
    y: Sequence[float],
    *,
    y_label: str,
    title: str = "",
    best: int | Sequence[int] | None = None,
    better: str | None = None,
) -> Figure:
    """Small multiples: one metric (``y``, one value per run) against each swept key in
    its own panel (``xs``: ``{axis label in words with unit: one value per run}``), for
    sweeps and searches whose runs vary several keys at once. Ticks as in
    `plot_report_metric`; ``best`` (with ``better``) starred in every panel, only for a
    metric with a known direction."""
    ys = np.asarray(y, float)
    int_y = all(_is_int(v) for v in y)
    for label, x in xs.items():
        if len(x) != len(ys):
            raise ValueError(f"{label}: {len(x)} values for {len(ys)} runs; pass one per run")
    bi = _best_list(best, better)
    n = len(xs)
    ncol = min(n, 3)
    nrow = -(-n // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.8 * ncol, 3.1 * nrow), squeeze=False,
                             sharey=True, layout="constrained")  # fmt: skip
    for ax, (label, x) in zip(axes.flat, xs.items(), strict=False):
        pos = _positions(list(x))
        ax.plot(pos, ys, "o", color="C0", ms=6, alpha=0.8, zorder=3)
        if bi:
            ax.plot([pos[i] for i in bi], ys[bi], "*", ms=16, color="gold", mec="black",
                    mew=0.8, zorder=5, label=f"best ({better} is better)")  # fmt: skip
        _x_ticks(ax, list(x), pos)
        ax.set_xlabel(label)
        ax.grid(True, alpha=0.3)
        if int_y:
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for row in axes:
        row[0].set_ylabel(y_label)
    if bi:
        axes.flat[0].legend(fontsize=8, loc="best", framealpha=0.85)
    if title:
        fig.suptitle(title, fontsize=10, family="monospace")
    return fig


def _axis_label(k: Any) -> str:
    """An axis in words with its unit, from what `describe` says of the key or metric."""
    return f"{k.words} [{k.unit}]" if k.unit else k.words


def plot_report_figure(
    runs: Sequence[Mapping[str, Any]],
    metric: str,
    swept: Sequence[str],
    *,
    x: str,
    describe: Callable[[str], Any],
    best: Sequence[int] = (),
) -> Figure:
    """The figure of one metric of ``fxspace report`` against a sweep's swept key(s):
    lines against ``x``, one per combination of the other swept keys
    (`plot_report_metric`), or one panel per swept key when the runs vary several keys
    at once — more than 6 combinations of the other keys, or none repeated, as in a
    search (`plot_report_grid`).

    **Arguments:**
    - `runs`: one mapping per run, holding ``metric`` (a finite number) and every swept key.
    - `metric`: the metric's dotted name (the y axis, the title).
    - `swept`: the swept keys; `x`: the one on the x axis of the lines.
    - `describe`: ``describe(name)`` → an object with ``words``, ``unit`` and ``better``
      (`fxspace.report.describe` for the experiment): the axes in words with units.
    - `best`: the indices (into ``runs``) of the best runs, starred with the metric's
      direction; empty for none.

    **Returns:** the `Figure`; its label (``fig.get_label()``) is the file stem the report
    saves it under: ``METRIC_vs_X`` (``_by_OTHERS``), or ``METRIC_vs_KEYS`` (panels).
    """
    vals, m, best = list(runs), metric, list(best)
    others = [k for k in swept if k != x]
    d = describe(m)
    kw = dict(y_label=_axis_label(d), title=m, best=best or None,
              better=d.better if best else None)  # fmt: skip
    combos = [tuple(json.dumps(r[k]) for k in others) for r in vals]
    sizes = [combos.count(c) for c in set(combos)]
    if others and (len(sizes) > 6 or max(sizes) < 2):
        # several keys vary at once (a search, a large grid): one panel per key
        xs = {_axis_label(describe(k)): [r[k] for r in vals] for k in swept}
        fig = plot_report_grid(xs, [r[m] for r in vals], **kw)
        name = f"{m}_vs_{'_'.join(swept)}"
    else:
        if len(others) == 1:
            u = describe(others[0]).unit
            group = [f"{r[others[0]]}" + (f" {u}" if u else "") for r in vals]
            glabel = describe(others[0]).words
        else:
            group = [", ".join(f"{k} = {r[k]}" for k in others) for r in vals]
            glabel = ""
        fig = plot_report_metric(
            [r[x] for r in vals], [r[m] for r in vals], x_label=_axis_label(describe(x)),
            group=group if others else None, group_label=glabel, **kw,
        )  # fmt: skip
        name = f"{m}_vs_{x}" + (f"_by_{'_'.join(others)}" if others else "")
    fig.set_label(name)
    return fig
