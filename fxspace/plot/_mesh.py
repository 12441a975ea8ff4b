"""Figures for mesh IK (Park, Kang & Kwon): shaded rest / target / deformed renders
(Figs. 4–8), time per frame naive vs factored (Fig. 9), time and error vs markers
(Fig. 10), and the regulariser comparison."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = [
    "plot_ik_poses",
    "plot_model_speedups",
    "plot_time_per_frame",
    "plot_vs_markers",
    "shade_mesh",
    "view_basis",
]


def view_basis(view_dir, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """``(3, 3)`` rows: screen right, screen up, and the viewing direction (unit)."""
    d = np.asarray(view_dir, dtype=np.float64)
    d = d / np.linalg.norm(d)
    u = np.asarray(up, dtype=np.float64)
    if abs(float(u @ d)) > 0.99:
        u = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    right = np.cross(d, u)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, d), d])


def shade_mesh(ax, vertices, faces, color="0.7", view_dir=(0.0, 0.0, -1.0), up=(0, 1, 0)):
    """Draw a triangle mesh shaded (Lambert, headlight) in orthographic projection along
    ``view_dir``, back to front (painter's algorithm); returns the 2-D basis used."""
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import to_rgb

    basis = view_basis(view_dir, up)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    tri = v[f]  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    lam = np.abs(n @ basis[2])
    depth = (tri @ basis[2]).mean(axis=1)
    order = np.argsort(-depth)  # far first
    xy = tri[order] @ basis[:2].T
    rgb = np.asarray(to_rgb(color))
    shade = (0.25 + 0.75 * lam[order])[:, None] * rgb[None]
    ax.add_collection(PolyCollection(xy, facecolors=shade, edgecolors="none"))
    lo, hi = xy.reshape(-1, 2).min(0), xy.reshape(-1, 2).max(0)
    pad = 0.05 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    return basis


def plot_ik_poses(
    faces: np.ndarray,
    rest: np.ndarray,
    target: np.ndarray,
    deformed: Mapping[int, tuple[np.ndarray, np.ndarray, np.ndarray]],
    title: str = "",
    view_dir=(0.0, 0.0, -1.0),
    up=(0.0, 1.0, 0.0),
) -> Figure:
    """Rest / target / deformed mesh for each marker count, shaded (the paper's Figs. 4–8).

    ``deformed`` maps a marker count to ``(vertices, marker targets, rest marker positions)``;
    meshes are rendered along ``view_dir`` (the camera the markers were placed from), rest
    markers blue, targets red.
    """
    rows = sorted(deformed)
    fig, axs = plt.subplots(len(rows), 3, figsize=(7.5, 2.8 * len(rows)), squeeze=False)
    for r, k in enumerate(rows):
        verts, tgt, rest_m = deformed[k]
        b = shade_mesh(axs[r, 0], rest, faces, "0.75", view_dir, up)
        axs[r, 0].scatter(*(np.asarray(rest_m) @ b[:2].T).T, s=6, c="tab:blue", zorder=3)
        shade_mesh(axs[r, 1], target, faces, "tab:green", view_dir, up)
        axs[r, 1].scatter(*(np.asarray(tgt) @ b[:2].T).T, s=6, c="tab:red", zorder=3)
        shade_mesh(axs[r, 2], verts, faces, "tab:orange", view_dir, up)
        axs[r, 2].scatter(*(np.asarray(tgt) @ b[:2].T).T, s=6, c="tab:red", zorder=3)
        axs[r, 0].set_ylabel(f"{k} marker{'s' if k > 1 else ''}")
    for c, name in enumerate(("rest", "target", "deformed (IK)")):
        axs[0, c].set_title(name)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_time_per_frame(times_ms: Mapping[str, np.ndarray], title: str = "") -> Figure:
    """Time per frame (ms) along the animation, one line per gradient form (Fig. 9)."""
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
    """One line per series against the number of markers (time: Fig. 10; vertex error)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    styles = [("o", "-"), ("s", "--"), ("^", ":"), ("D", "-."), ("v", "-"), ("x", "--")]
    for i, (name, v) in enumerate(values.items()):  # distinct styles: equal series stay visible
        m, ls = styles[i % len(styles)]
        ax.plot(list(counts), list(v), marker=m, ls=ls, label=name, alpha=0.85)
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


def plot_model_speedups(
    models: Sequence[str],
    ratios: Mapping[str, Sequence[float]],
    title: str = "",
    paper: float | None = 3.14,
) -> Figure:
    """Fig. 9 over models: the naive / factored time ratio per model, one bar group per
    model and one bar per measure (``ratios[measure][model]``: e.g. per gradient
    evaluation, per solved frame cold / warm), with the paper's mean speed-up as a line."""
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(models), 3.6))
    n = max(len(ratios), 1)
    x = np.arange(len(models))
    for i, (name, vals) in enumerate(ratios.items()):
        ax.bar(x + (i - (n - 1) / 2) * 0.8 / n, vals, width=0.8 / n, label=name)
    if paper is not None:
        ax.axhline(paper, color="k", lw=0.8, ls="--", label=f"paper mean {paper:g}x")
    ax.axhline(1.0, color="0.5", lw=0.6)
    ax.set_xticks(x, list(models), rotation=15)
    ax.set_ylabel("naive / factored time")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
