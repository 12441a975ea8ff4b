"""Figures of the expression space: the threshold sweep and the 2-D embedding."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = ["plot_sweep", "plot_embedding", "plot_embedding_panels"]


def plot_sweep(
    thresholds: np.ndarray,
    scores: np.ndarray,
    connected: np.ndarray,
    marks: dict[str, float] | None = None,
    connecting: float | None = None,
    reference: tuple[float, str] | None = (0.9647, "seed paper r = 0.9647"),
    mean_degree: np.ndarray | None = None,
    *,
    chosen: str | None = None,
    largest: float | None = None,
    paper_point: tuple[float, float] | None = None,
    units: str = "mm",
) -> Figure:
    """Pearson r against the threshold ε (log scale).

    Disconnected ε (r undefined) are a rug of crosses on the bottom edge of the axes — not
    at a height that reads as an r value. Criteria that pick the same ε share one line and
    one legend entry naming all of them, so none hides another. `chosen` names the
    criterion that chose ε (in the title, and its line is drawn bold); `largest` marks the
    largest pairwise distance (the sweep's upper end, a complete graph); `paper_point`
    ``(ε, r)`` marks the paper's choice (Kim & Jung: 230 mm, r = 0.9647).
    """
    th = np.asarray(thresholds, float)
    r = np.asarray(scores, float)
    conn = np.asarray(connected, bool)
    fig, ax = plt.subplots(figsize=(7.0, 5.6), layout="constrained")
    # data on top (z 4), the paper's star above everything (z 6), criteria under the data
    ax.plot(th[conn], r[conn], "o-", color="C0", zorder=4, label="Pearson r (connected)")
    if (~conn).any():
        ax.plot(
            th[~conn],
            np.full((~conn).sum(), 0.03),
            "x",
            color="C3",
            transform=ax.get_xaxis_transform(),  # x in data, y in axes fraction
            clip_on=False,
            zorder=4,
            label="disconnected ε (r undefined)",
        )
    _draw_criteria(ax, marks, connecting, chosen)
    if connecting is not None:
        # the connecting ε as the edge of a shaded band (no ε left of it connects the
        # graph) and a thin line drawn above the criteria's lines, so one that picks the
        # same ε cannot hide it
        if th.size and th.min() < connecting:
            ax.axvspan(th.min() / 1.1, connecting, color="0.9", zorder=0,
                       label="below the connecting ε: graph disconnected")  # fmt: skip
        ax.plot([connecting, connecting], [0.0, 1.0], color="k", ls=":", lw=1.2, marker="v",
                markevery=[1], ms=8, transform=ax.get_xaxis_transform(), clip_on=False,
                zorder=5, label=f"connecting ε = {connecting:.4g} (▼)")  # fmt: skip
    if largest is not None:
        ax.axvline(largest, color="0.2", ls="-", lw=0.8, zorder=2,
                   label=f"largest distance {largest:.4g}")  # fmt: skip
    if reference is not None:
        ax.axhline(reference[0], color="0.3", lw=0.8, ls="-.", zorder=1, label=reference[1])
    if paper_point is not None:
        ax.plot(
            *paper_point,
            "*",
            color="k",
            mec="w",
            ms=13,
            zorder=6,
            clip_on=False,
            label=f"paper: ε = {paper_point[0]:g} {units}, r = {paper_point[1]:.4f}",
        )
    ax.set_xscale("log")
    ends = [v for v in (*th[np.isfinite(th) & (th > 0)], connecting, largest) if v]
    if ends:  # a margin, so a line at either end is not drawn on the frame
        ax.set_xlim(min(ends) / 1.1, max(ends) * 1.1)
    _plain_log_ticks(ax.xaxis)
    ax.set_xlabel(f"threshold ε ({units}: distance between marker-distance matrices)")
    ax.set_ylabel("Pearson r (geodesic vs 2-D distance)")
    if mean_degree is not None:
        _draw_mean_degree(ax, th, mean_degree)
    # the legend under the axes: it covers no point, the paper's star included
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2,
              frameon=False)  # fmt: skip
    title = "Threshold sweep"
    if chosen is not None and chosen in (marks or {}):
        title += f": ε = {marks[chosen]:.4g} chosen by {chosen}"  # type: ignore[index]
    ax.set_title(title, fontsize=10)
    return fig


def _draw_criteria(ax, marks, connecting, chosen) -> None:
    """One vertical line per distinct ε in ``marks``, naming every criterion that picks
    it (the ``chosen`` one bold, one that picks the connecting ε said so)."""
    groups: dict[float, list[str]] = {}
    for name, t in (marks or {}).items():
        key = next((g for g in groups if np.isclose(g, t, rtol=1e-9, atol=0.0)), float(t))
        groups.setdefault(key, []).append(name)
    styles = ("--", "-.", (0, (1, 1)), (0, (5, 1, 1, 1)))
    for k, (t, names) in enumerate(groups.items()):
        bold = chosen is not None and chosen in names
        same = connecting is not None and np.isclose(t, connecting, rtol=1e-6, atol=0.0)
        ax.axvline(
            t,
            color=f"C{k + 1}",
            ls=styles[k % len(styles)],
            lw=(2.6 if bold else 1.4) + 0.8 * (len(names) - 1),
            zorder=2,
            label=f"{' = '.join(names)}: ε = {t:.4g}"
            + (" (chosen)" if bold else "")
            + (" = connecting ε" if same else ""),
        )


def _draw_mean_degree(ax, th: np.ndarray, mean_degree) -> None:
    """The graph's mean degree against ε, a grey line on a second (log) y axis beneath
    the r axis's contents."""
    ax2 = ax.twinx()
    ax2.plot(th, np.asarray(mean_degree), color="0.6", lw=1, zorder=1)
    ax2.set_ylabel("mean degree (grey line)", color="0.4")
    ax2.set_yscale("log")
    _plain_log_ticks(ax2.yaxis)
    ax2.tick_params(axis="y", colors="0.4")
    ax.set_zorder(ax2.get_zorder() + 1)  # r, the criteria and the star above the grey line
    ax.patch.set_visible(False)


def _plain_log_ticks(axis) -> None:
    """Ticks of a log axis as plain numbers at 1, 2 and 5 × 10ᵏ (no crowded "3×10²4×10²"
    minor labels)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def plot_embedding(
    embedding: np.ndarray,
    color: np.ndarray,
    title: str = "",
    categories: Sequence[str] | None = None,
    ax: plt.Axes | None = None,
    cmap: str = "viridis",
) -> Figure:
    """Scatter of the 2-D expression space; ``categories`` names integer colours."""
    Y = np.asarray(embedding)
    c = np.asarray(color)
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.2, 4.6))
    else:
        fig = ax.figure
    if categories is not None:
        for k, name in enumerate(categories):
            m = c == k
            ax.scatter(Y[m, 0], Y[m, 1], s=4, color=f"C{k % 10}", label=name)
        ax.legend(markerscale=3, fontsize=7)
    else:
        sc = ax.scatter(Y[:, 0], Y[:, 1], s=4, c=c, cmap=cmap)
        fig.colorbar(sc, ax=ax, shrink=0.8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("MDS 1")
    ax.set_ylabel("MDS 2")
    ax.set_title(title)
    return fig


def plot_embedding_panels(
    embedding: np.ndarray,
    take: np.ndarray,
    time: np.ndarray,
    take_names: Sequence[str],
    title: str = "",
) -> Figure:
    """Two panels: coloured by take and by time within the take."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8))
    plot_embedding(
        embedding,
        take,
        "by take" if len(set(take_names)) > 1 and "neutral" not in take_names else "by expression",
        categories=take_names,
        ax=axes[0],
    )
    plot_embedding(embedding, time, "by time (frame in take)", ax=axes[1])
    fig.suptitle(title)
    fig.tight_layout()
    return fig
