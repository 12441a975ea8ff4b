"""Figures for mesh IK (Park, Kang & Kwon): poses, time per frame, time and error vs markers."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = ["plot_ik_poses", "plot_time_per_frame", "plot_vs_markers"]


def _mesh2d(ax, vertices, faces, color, axes2d=(0, 1)):
    v = np.asarray(vertices)[:, list(axes2d)]
    ax.triplot(v[:, 0], v[:, 1], np.asarray(faces), color=color, lw=0.15)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def plot_ik_poses(
    faces: np.ndarray,
    rest: np.ndarray,
    target: np.ndarray,
    deformed: Mapping[int, tuple[np.ndarray, np.ndarray, np.ndarray]],
    title: str = "",
    axes2d: tuple[int, int] = (0, 1),
) -> Figure:
    """Rest / target / deformed mesh for each marker count (like the paper's figures).

    ``deformed`` maps a marker count to ``(vertices, marker targets, rest marker positions)``;
    meshes are drawn as wireframes projected on the ``axes2d`` coordinates.
    """
    rows = sorted(deformed)
    fig, axs = plt.subplots(len(rows), 3, figsize=(7.5, 2.6 * len(rows)), squeeze=False)
    for r, k in enumerate(rows):
        verts, tgt, rest_m = deformed[k]
        _mesh2d(axs[r, 0], rest, faces, "0.5", axes2d)
        axs[r, 0].scatter(*np.asarray(rest_m)[:, list(axes2d)].T, s=6, c="tab:blue")
        _mesh2d(axs[r, 1], target, faces, "tab:green", axes2d)
        axs[r, 1].scatter(*np.asarray(tgt)[:, list(axes2d)].T, s=6, c="tab:red")
        _mesh2d(axs[r, 2], verts, faces, "tab:orange", axes2d)
        axs[r, 2].scatter(*np.asarray(tgt)[:, list(axes2d)].T, s=6, c="tab:red")
        axs[r, 0].set_ylabel(f"{k} marker{'s' if k > 1 else ''}")
    for c, name in enumerate(("rest", "target", "deformed (IK)")):
        axs[0, c].set_title(name)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_time_per_frame(times_ms: Mapping[str, np.ndarray], title: str = "") -> Figure:
    """Time per frame (ms) along the animation, one line per gradient form."""
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    for name, t in times_ms.items():
        t = np.asarray(t)
        ax.plot(np.arange(t.size), t, lw=1, label=f"{name} (mean {t.mean():.2f} ms)")
    ax.set_xlabel("frame")
    ax.set_ylabel("time per frame [ms]")
    ax.set_ylim(bottom=0)
    ax.legend()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig


def plot_vs_markers(
    counts: Sequence[int],
    values: Mapping[str, Sequence[float]],
    ylabel: str,
    title: str = "",
    logy: bool = False,
) -> Figure:
    """One line per series against the number of markers (time or vertex error)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    for name, v in values.items():
        ax.plot(list(counts), list(v), "o-", label=name)
    ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_xticks(list(counts), [str(c) for c in counts])
    ax.set_xlabel("number of markers")
    ax.set_ylabel(ylabel)
    ax.legend()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig
