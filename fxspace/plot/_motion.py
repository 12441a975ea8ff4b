"""Figures for parametric motion synthesis: parameter spaces, stick-figure filmstrips, clocks,
speed against the joy weight, and the §3.2 re-placement of the upper samples."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = [
    "plot_parameter_space",
    "plot_filmstrip",
    "plot_clocks",
    "plot_speed_vs_weight",
    "plot_replacement",
]


def plot_parameter_space(
    samples, examples, requested=None, achieved=None, title: str = ""
) -> Figure:
    """Sampled parameters (dots), examples (squares) and requested → achieved queries.
    2-D parameters are drawn as they are; 3-D ones as the x–z and x–y projections."""
    samples, examples = np.asarray(samples), np.asarray(examples)
    d = samples.shape[1]
    pairs = [(0, 1)] if d == 2 else [(0, 2), (0, 1)]
    labels = ["x", "z"] if d == 2 else ["x", "y", "z"]
    fig, axes = plt.subplots(1, len(pairs), figsize=(5.5 * len(pairs), 5), squeeze=False)
    for ax, (a, b) in zip(axes[0], pairs, strict=True):
        ax.scatter(samples[:, a], samples[:, b], s=4, c="0.6", label=f"{len(samples)} samples")
        ax.scatter(examples[:, a], examples[:, b], s=60, marker="s", c="C0", label="examples")
        if requested is not None:
            req = np.asarray(requested)
            ax.scatter(req[:, a], req[:, b], s=40, marker="x", c="C3", label="requested")
            if achieved is not None:
                ach = np.asarray(achieved)
                ax.scatter(
                    ach[:, a],
                    ach[:, b],
                    s=25,
                    facecolors="none",
                    edgecolors="C2",
                    label="achieved (k-NN)",
                )
                for p, q in zip(req, ach, strict=True):
                    ax.plot([p[a], q[a]], [p[b], q[b]], c="C3", lw=0.8)
        ax.set_xlabel(f"{labels[a] if d == 3 else labels[0]} (m)")
        ax.set_ylabel(f"{labels[b] if d == 3 else labels[1]} (m)")
        ax.set_aspect("equal", adjustable="datalim")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(title)
    return fig


def plot_filmstrip(positions, parents, n_panels: int = 8, title: str = "") -> Figure:
    """Side-by-side stick figures (x–y view, each centred on its root) of ``n_panels`` frames
    of ``positions`` ``(T, J, 3)``, plus the root and toe paths seen from above."""
    X = np.asarray(positions)
    T = X.shape[0]
    frames = np.linspace(0, T - 1, n_panels).round().astype(int)
    fig, axes = plt.subplots(
        1,
        n_panels + 1,
        figsize=(2.0 * n_panels + 4, 4),
        gridspec_kw={"width_ratios": [1] * n_panels + [2]},
    )
    for ax, f in zip(axes[:-1], frames, strict=True):
        P = X[f] - np.asarray([X[f, 0, 0], 0.0, X[f, 0, 2]])
        for j, p in enumerate(parents):
            if p >= 0:
                ax.plot([P[p, 0], P[j, 0]], [P[p, 1], P[j, 1]], c="k", lw=1.5)
        ax.set_xlim(-1, 1)
        ax.set_ylim(-0.05, 2.0)
        ax.set_aspect("equal")
        ax.set_title(f"frame {f}", fontsize=8)
        ax.axis("off")
    ax = axes[-1]
    ax.plot(X[:, 0, 0], X[:, 0, 2], label="root")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title("root path (top view)", fontsize=8)
    fig.suptitle(title)
    return fig


def plot_clocks(clocks: dict, lam=None, title: str = "") -> Figure:
    """Lower clock ``u`` and upper clock ``v`` per output frame for each α (``{α: (u, v)}``),
    and ``v`` against ``u`` with the alignment curve λ."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for i, (alpha, (u, v)) in enumerate(sorted(clocks.items())):
        a1.plot(u, c=f"C{i}", ls="--", lw=1)
        a1.plot(v, c=f"C{i}", label=f"α={alpha:g}")
        a2.plot(u, v, c=f"C{i}", label=f"α={alpha:g}")
    if lam is not None:
        lam = np.asarray(lam)
        a2.plot(np.arange(lam.size), lam, c="k", lw=0.8, label="λ")
    a1.set_xlabel("output frame")
    a1.set_ylabel("generic time (reference frames); -- lower u, — upper v")
    a2.set_xlabel("lower clock u")
    a2.set_ylabel("upper clock v")
    a1.legend(fontsize=8)
    a2.legend(fontsize=8)
    fig.suptitle(title)
    return fig


def plot_speed_vs_weight(
    weights,
    speeds: dict,
    ylabel: str = "ground speed (m/s)",
    title: str = "",
    xlabel: str = "joy weight (sad = 1 − joy)",
) -> Figure:
    """Speed of the synthesised motion against an upper-body weight (Ha & Han §4: a higher
    joy weight makes the whole walk faster), one line per α (``{α: speeds}``); ``xlabel``
    names the weight's axis from the clips' labels (e.g. ``proud weight (tired = 1 −
    proud)``)."""
    fig, ax = plt.subplots(figsize=(5.5, 4))
    w = np.asarray(weights)
    for i, (alpha, v) in enumerate(sorted(speeds.items())):
        ax.plot(w, np.asarray(v), marker="o", c=f"C{i}", label=f"α={alpha:g}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(title)
    return fig


def plot_replacement(stale, replaced, exact, title: str = "") -> Figure:
    """Upper-space samples (root frame) for a new lower parameter: stored ``ṗ`` (grey), the
    Horn re-placed ones (§3.2, green) and the exact re-sampled ones (black rings), x–z and
    x–y projections (the paper's Figs. 2 and 5)."""
    stale, replaced, exact = (np.asarray(a) for a in (stale, replaced, exact))
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, (a, b), lab in zip(axes, [(0, 2), (0, 1)], [("x", "z"), ("x", "y")], strict=True):
        ax.scatter(stale[:, a], stale[:, b], s=4, c="0.7", label="stored ṗ (old lower)")
        ax.scatter(replaced[:, a], replaced[:, b], s=4, c="C2", label="re-placed (Horn)")
        ax.scatter(
            exact[:, a],
            exact[:, b],
            s=12,
            facecolors="none",
            edgecolors="k",
            lw=0.4,
            label="exact re-sampling",
        )
        ax.set_xlabel(f"{lab[0]} (m)")
        ax.set_ylabel(f"{lab[1]} (m)")
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return fig


def plot_timewarp(t, warped: dict, plain: dict, examples: dict, title: str = "") -> Figure:
    """Ha & Han Fig. 3 as numbers: the same blends with and without time-warping.

    ``t`` ``(T,)`` reference frames; ``warped`` / ``plain`` ``{label: (T,) toe height}``
    of each blend with the registration (eq. 1's ``C_i``) and with plain linear time
    normalisation; ``examples`` ``{label: (T_i,) toe height}`` of the blended clips. A
    blend without registration averages feet in different phases: the foot no longer
    lands (it floats or slides)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
    for ax, (name, curves) in zip(axes, (("with time-warp", warped), ("without", plain)),
                                  strict=True):  # fmt: skip
        for lab, h in examples.items():
            ax.plot(np.linspace(0, t[-1], len(h)), h, color="0.75", lw=1, label=lab)
        for lab, h in curves.items():
            ax.plot(t, h, lw=1.8, label=lab)
        ax.set_title(name)
        ax.set_xlabel("reference frame")
    axes[0].set_ylabel("left toe height (m)")
    axes[1].legend(fontsize=7, loc="upper right")
    fig.suptitle(title)
    fig.tight_layout()
    return fig
