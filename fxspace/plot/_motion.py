"""Figures for parametric motion synthesis: parameter spaces, stick-figure filmstrips, clocks."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = ["plot_parameter_space", "plot_filmstrip", "plot_clocks"]


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
