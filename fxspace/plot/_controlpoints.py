"""Figures for segmentation and control-point editing (matplotlib only here)."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from fxspace.rigid import principal_axes

__all__ = ["plot_segmentation", "plot_control_points", "plot_reconstruction_frames"]


def plot_segmentation(seg, n_channels: int = 3, rate: float | None = None) -> Figure:
    """Summary channels, their fused-lasso fit and the segment boundaries.

    ``seg`` is a `fxspace.Segmentation`.
    """
    Z = np.asarray(seg.summary)
    B = np.asarray(seg.fit)
    T = Z.shape[0]
    t = np.arange(T) / rate if rate else np.arange(T)
    k = min(n_channels, Z.shape[1])
    fig, axes = plt.subplots(k + 1, 1, figsize=(8, 1.6 * (k + 1)), sharex=True)
    for j in range(k):
        ax = axes[j]
        ax.plot(t, Z[:, j], color="0.6", lw=1, label="series")
        ax.plot(t, B[:, j], color="C0", lw=1.5, label="fused-lasso fit")
        ax.set_ylabel(f"PC {j + 1}")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].plot(t, np.asarray(seg.jump_energy), color="C3", lw=1)
    axes[-1].set_ylabel("jump energy")
    for ax in axes:
        for b in np.asarray(seg.boundaries):
            ax.axvline(t[b], color="k", lw=0.8, ls="--")
    axes[-1].set_xlabel("time (s)" if rate else "frame")
    axes[0].set_title(f"segmentation: {len(seg.boundaries) - 1} segments, λ = {seg.lam:.3g}")
    fig.tight_layout()
    return fig


def _project(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Front view: the two principal axes of the vertices, depth the third."""
    mu, vt = principal_axes(np.asarray(V))
    return vt, mu


def plot_control_points(
    vertices: np.ndarray,
    labels: np.ndarray,
    faces: np.ndarray | None = None,
    medoids: Sequence[int] | None = None,
) -> Figure:
    """Vertices coloured by their cluster (control point), front view."""
    V = np.asarray(vertices)
    vt, mu = _project(V)
    uv = (V - mu) @ vt[:2].T
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.scatter(uv[:, 0], uv[:, 1], c=np.asarray(labels), cmap="tab20", s=2)
    if medoids is not None:
        m = np.asarray(medoids)
        m = m[m >= 0]
        ax.scatter(uv[m, 0], uv[m, 1], c="k", s=18, marker="x")
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(f"{int(np.max(labels)) + 1} control-point regions")
    return fig


def plot_reconstruction_frames(
    frames: Sequence[np.ndarray],
    titles: Sequence[str],
    faces: np.ndarray | None = None,
    reference: np.ndarray | None = None,
    up: np.ndarray | None = None,
) -> Figure:
    """Side-by-side front views of one frame (e.g. original / linear / ours / edited).

    Panels are shaded by depth; with ``reference`` (the original frame, shown first) the
    other panels are coloured by the per-vertex error ``‖v − v_ref‖`` (one colour scale).
    ``up``: a 3-vector that should point up in the view (e.g. chin → forehead).
    """
    Vs = [np.asarray(f) for f in frames]
    vt, mu = _project(Vs[0])
    n = len(Vs)
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 3.6))
    axes = np.atleast_1d(axes)
    if reference is not None:
        errs = [np.linalg.norm(V - np.asarray(reference), axis=1) for V in Vs]
        vmax = max(float(np.percentile(e, 99)) for e in errs) or 1.0
    if up is not None:  # orient the view: the image y axis along `up`
        u = np.asarray(up, dtype=float)
        y = u - (u @ vt[2]) * vt[2]
        y /= np.linalg.norm(y)
        vt = np.stack([np.cross(y, vt[2]), y, vt[2]])
    for j, (V, ax) in enumerate(zip(Vs, axes, strict=True)):
        p = (V - mu) @ vt.T
        err_colour = reference is not None and j > 0
        c = errs[j] if err_colour else p[:, 2]
        kw = dict(vmin=0, vmax=vmax, cmap="magma") if err_colour else dict(cmap="bone")
        if faces is not None:
            tpc = ax.tripcolor(p[:, 0], p[:, 1], np.asarray(faces), c, shading="gouraud", **kw)
        else:
            tpc = ax.scatter(p[:, 0], p[:, 1], c=c, s=2, **kw)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(titles[j], fontsize=10)
    if reference is not None:
        fig.colorbar(tpc, ax=list(axes), shrink=0.7, label="distance to original (mm)")
    return fig


def plot_scene_errors(errors, boundaries: Sequence[int] | None = None) -> Figure:
    """Eq. (1) per segment: linear interpolation vs the control-point model (log scale),
    with each segment's ratio; ``errors`` is a `fxspace.SceneErrors`."""
    lin = np.asarray(errors.linear, float)
    mod = np.asarray(errors.model, float)
    k = np.arange(len(lin))
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.bar(k - 0.2, lin, 0.4, label="linear interpolation", color="#bbbbbb")
    ax.bar(k + 0.2, mod, 0.4, label="control points", color="#d04040")
    for i in k:
        ax.text(i + 0.2, max(mod[i], 1e-12), f"{errors.ratio[i]:.3f}", ha="center",
                va="bottom", fontsize=7)  # fmt: skip
    ax.set_yscale("log")
    labels = [str(i) for i in k]
    if boundaries is not None:
        b = list(boundaries)
        labels = [f"{i}\n{b[i]}–{b[i + 1]}" for i in k]
    ax.set_xticks(k, labels, fontsize=7)
    ax.set_xlabel("segment (frames)")
    ax.set_ylabel("error, eq. (1)")
    ax.set_title(
        f"whole scene: ratio {errors.ratio_scene:.4f} "
        f"({errors.model_scene:.3g} vs linear {errors.linear_scene:.3g})",
        fontsize=9,
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
