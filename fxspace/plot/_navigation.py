"""Figures and animation of the hierarchy and of a navigation (seed paper figs. 4–8).

- `plot_level`: one level — frames (grey), centres shown at their frames (numbered),
  links dashed, an optional route (key centres ringed, frame path as a line).
- `plot_levels_grid`: every level side by side, with each level's route.
- `face_wireframe`: a fixed wireframe for a marker set (Delaunay triangulation of
  the neutral frame's front projection, long hull edges removed).
- `write_navigation_animation`: GIF (Pillow) or MP4 (ffmpeg, when present) of the
  2-D path with a moving cross beside the 3-D face.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from fxspace.rigid import principal_axes

__all__ = [
    "plot_level",
    "plot_levels_grid",
    "plot_link_radius_sweep",
    "face_frame",
    "face_wireframe",
    "write_navigation_animation",
]


def _links_segments(xy_c: np.ndarray, links) -> np.ndarray:
    """Segments of a level's links (a ``csr_array``)."""
    from fxspace.navigation import link_pairs

    i, j = link_pairs(links)
    return np.stack([xy_c[i], xy_c[j]], axis=1)


def _draw_level(
    ax,
    hierarchy,
    level: int,
    route=None,
    *,
    show_links: bool = True,
    label_centres: bool | None = None,
    show_frames: bool = True,
) -> None:
    lv = hierarchy.levels[level]
    xy = np.asarray(hierarchy.embedding)
    c = xy[lv.center_frames]
    if show_frames:
        ax.scatter(xy[:, 0], xy[:, 1], s=3, c="0.8", lw=0, zorder=1)
    if show_links and lv.links is not None and lv.n_clusters <= 400:
        bridges = getattr(lv, "bridges", None)
        plain = lv.links
        if bridges is not None and bridges.nnz:
            plain = lv.links.astype(np.int8) - bridges.astype(np.int8)
            plain.eliminate_zeros()
            ax.add_collection(LineCollection(
                _links_segments(c, bridges), colors="tab:orange", linewidths=1.0,
                alpha=0.9, zorder=2,
            ))  # fmt: skip
        segs = _links_segments(c, plain)
        if len(segs):
            ax.add_collection(
                LineCollection(
                    segs,
                    colors="tab:blue",
                    linestyles="dashed",
                    linewidths=0.6,
                    alpha=float(np.clip(12.0 / math.sqrt(len(segs)), 0.12, 0.6)),  # many: fainter
                    zorder=2,
                )
            )
    size = max(4.0, 60.0 / math.sqrt(max(lv.n_clusters, 1) / 10))
    ax.scatter(c[:, 0], c[:, 1], s=size, c="tab:blue", edgecolors="k", linewidths=0.3, zorder=3)
    if label_centres is None:
        label_centres = lv.n_clusters <= 40
    if label_centres:
        for k, (x, y) in enumerate(c):
            ax.annotate(
                str(k), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points", zorder=5
            )
    if route is not None:
        p = xy[np.asarray(route.frames)]
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:red", lw=1.5, zorder=4)
        kc = xy[np.asarray(route.key_frames)]
        ax.scatter(
            kc[:, 0],
            kc[:, 1],
            s=size * 2.5,
            facecolors="none",
            edgecolors="tab:red",
            linewidths=1.5,
            zorder=5,
        )
    ax.set_title(
        f"level {level}: {lv.n_clusters} centres"
        + (f", ρ = {lv.radius:.3g}" if np.isfinite(lv.radius) else ""),
        fontsize=9,
    )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xticks([])
    ax.set_yticks([])


def plot_level(
    hierarchy, level: int, route=None, *, show_links: bool = True, label_centres: bool | None = None
) -> Figure:
    """One level of the hierarchy: centres at their frames, links dashed, the route."""
    fig, ax = plt.subplots(figsize=(6, 5))
    _draw_level(ax, hierarchy, level, route, show_links=show_links, label_centres=label_centres)
    return fig


def plot_levels_grid(
    hierarchy,
    routes: Sequence | None = None,
    ncols: int = 3,
    title: str | None = None,
    *,
    panel_width: float = 4.2,
    fontsize: float = 14.0,
) -> Figure:
    """Every level in a grid; ``routes`` (e.g. from `fxspace.navigate`) are drawn on
    their levels; `title` (e.g. the ε and the criterion that chose it) above them.

    Made to be read on a page: ``ncols`` panels a row, each ``panel_width`` inches wide
    and as tall as the embedding's extent needs (no empty bands around a flat space),
    titles and legend at ``fontsize``; links drawn fainter as a level holds more of them.
    """
    n = len(hierarchy.levels)
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    xy = np.asarray(hierarchy.embedding, float)
    ext = np.ptp(xy, axis=0) if xy.size else np.ones(2)
    aspect = float(np.clip(ext[1] / max(ext[0], 1e-12), 0.45, 1.0))
    ph = panel_width * aspect + 0.5  # + the panel's title
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(panel_width * ncols, ph * nrows + 1.3 + (0.4 if title else 0)),
        squeeze=False, layout="constrained",
    )  # fmt: skip
    by_level = {r.level: r for r in (routes or ())}
    bridged = False
    for k in range(nrows * ncols):
        ax = axes.flat[k]
        if k < n:
            _draw_level(ax, hierarchy, k, by_level.get(k), label_centres=False)
            ax.title.set_fontsize(fontsize)
            b = getattr(hierarchy.levels[k], "bridges", None)
            bridged |= b is not None and bool(b.nnz if hasattr(b, "nnz") else np.any(b))
        else:
            ax.axis("off")
    fig.legend(handles=_levels_legend(bool(by_level), bridges=bridged), loc="outside lower center",
               ncol=3, fontsize=fontsize - 1, frameon=False)  # fmt: skip
    if title:
        fig.suptitle(title, fontsize=fontsize + 1)
    return fig


def plot_link_radius_sweep(sweep, chosen: float | None = None) -> Figure:
    """The ρ experiment (`fxspace.navigation.link_radius_sweep`): per level, the links and
    the fraction of centre pairs a route can join (coverage) against the ρ scale; the
    chosen scale (`choose_link_scale`) marked."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    cmap = plt.get_cmap("viridis")
    L = len(sweep.levels)
    for k in range(L):
        col = cmap(k / max(L - 1, 1))
        lab = f"level {int(sweep.levels[k])} ({int(sweep.centres[k])} centres)"
        a1.plot(sweep.scales, sweep.links[k], "o-", color=col, ms=3, label=lab)
        a2.plot(sweep.scales, sweep.coverage[k], "o-", color=col, ms=3, label=lab)
    a1.set_yscale("log")
    a1.set_ylabel("links (pairs of centres)")
    a2.set_ylabel("coverage: centre pairs joined through links")
    a2.set_ylim(-0.03, 1.03)
    for ax in (a1, a2):
        ax.set_xlabel("ρ scale (× the level's median centre spacing)")
        if chosen is not None:
            ax.axvline(chosen, color="tab:red", ls="--", lw=1, label=f"chosen: {chosen:g}")
    a2.legend(fontsize=7, loc="lower left")
    fig.suptitle("Link radius ρ by experiment (Kim & Jung §4.2): the largest scale that "
                 "keeps every level connected", fontsize=10)  # fmt: skip
    fig.tight_layout()
    return fig


def _levels_legend(with_route: bool, bridges: bool = True) -> list:
    """Legend handles of `plot_levels_grid` (what each mark in a level means; the bridge
    entry only where a level has bridges)."""
    from matplotlib.lines import Line2D

    h = [
        Line2D([], [], ls="", marker="o", ms=4, color="0.7", label="frame"),
        Line2D([], [], ls="", marker="o", ms=7, mfc="tab:blue", mec="k", label="cluster centre"),
        Line2D([], [], ls="--", color="tab:blue", lw=1.0, label="link between centres"),
    ]
    if bridges:
        h.append(Line2D([], [], color="tab:orange", lw=1.2,
                        label="bridge (not a link by the ρ rule)"))  # fmt: skip
    if with_route:
        h += [
            Line2D([], [], color="tab:red", lw=1.5, label="route"),
            Line2D([], [], ls="", marker="o", ms=8, mfc="none", mec="tab:red", label="key frame"),
        ]
    return h


def face_frame(neutral: np.ndarray, names: Sequence[str] | None = None) -> np.ndarray:
    """(3, 3) rows: the face's right, up and out axes from a PCA of the neutral frame; with
    marker names, 'up' points from the chin to the forehead."""
    p = np.asarray(neutral, np.float64)
    _, Vt = principal_axes(p)
    right, up = Vt[0], Vt[1]
    if names is not None:
        low = [n.lower() for n in names]
        top = [i for i, n in enumerate(low) if "forehead" in n]
        bot = [i for i, n in enumerate(low) if n.startswith("chin")]
        if top and bot:
            d = p[top].mean(0) - p[bot].mean(0)
            # the axis closest to the chin→forehead direction is 'up'
            if abs(d @ Vt[0]) > abs(d @ Vt[1]):
                right, up = Vt[1], Vt[0]
            up = up if d @ up > 0 else -up
    out = np.cross(right, up)
    return np.stack([right, up, out])


def face_wireframe(
    neutral: np.ndarray, names: Sequence[str] | None = None, max_edge_factor: float = 2.5
) -> np.ndarray:
    """(E, 2) marker-index edges: Delaunay triangulation of the neutral frame's front
    projection, dropping edges longer than ``max_edge_factor`` × the median edge."""
    from matplotlib.tri import Triangulation

    p = np.asarray(neutral, np.float64)
    R = face_frame(p, names)
    uv = (p - p.mean(0)) @ R[:2].T
    tri = Triangulation(uv[:, 0], uv[:, 1])
    e = np.asarray(tri.edges)
    length = np.linalg.norm(uv[e[:, 0]] - uv[e[:, 1]], axis=1)
    keep = length <= max_edge_factor * np.median(length)
    return e[keep]


def _face_coords(pos: np.ndarray, R: np.ndarray, centre: np.ndarray) -> np.ndarray:
    q = (pos - centre) @ R.T  # right, up, out
    return np.stack([q[..., 0], -q[..., 2], q[..., 1]], axis=-1)  # x right, y depth, z up


def write_navigation_animation(
    path: str | Path,
    play,
    embedding: np.ndarray,
    *,
    edges: np.ndarray | None = None,
    route=None,
    names: Sequence[str] | None = None,
    max_frames: int = 240,
    dpi: int = 80,
    title: str = "",
) -> Path:
    """Write the playback ``play`` (`fxspace.Playback`) as an animation: the 2-D
    expression space with the path and a moving cross, beside the 3-D face (markers joined
    by ``edges``, default `face_wireframe` of the first frame).

    ``path`` ending in ``.mp4`` needs ffmpeg (falls back to ``.gif`` with Pillow when it is
    absent). Output is written to a temporary name and renamed (atomic). Returns the path
    written.
    """
    from matplotlib import animation
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    from fxspace.runs import write_bytes_atomic

    path = Path(path)
    if path.suffix == ".mp4" and shutil.which("ffmpeg") is None:
        path = path.with_suffix(".gif")
    xy = np.asarray(embedding)
    P = np.asarray(play.positions)
    K = len(P)
    sel = np.unique(np.linspace(0, K - 1, min(K, max_frames)).round().astype(int))
    R = face_frame(P[0], names)
    centre = P[0].mean(0)
    F = _face_coords(P, R, centre)
    if edges is None:
        edges = face_wireframe(P[0], names)
    edges = np.asarray(edges)

    fig = plt.figure(figsize=(9, 4.5), dpi=dpi)
    ax2 = fig.add_subplot(1, 2, 1)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    ax2.scatter(xy[:, 0], xy[:, 1], s=2, c="0.8", lw=0)
    pxy = np.asarray(play.xy)
    ax2.plot(pxy[:, 0], pxy[:, 1], "-", color="tab:red", lw=1.2)
    if route is not None:
        kc = xy[np.asarray(route.key_frames)]
        ax2.scatter(kc[:, 0], kc[:, 1], s=40, facecolors="none", edgecolors="tab:red")
    (cross,) = ax2.plot([pxy[0, 0]], [pxy[0, 1]], "k+", ms=16, mew=2.5)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xticks([])
    ax2.set_yticks([])
    ax2.set_title(title or "expression space", fontsize=9)
    lines = Line3DCollection(F[0][edges], colors="0.3", linewidths=0.7)
    ax3.add_collection3d(lines)
    dots = ax3.scatter(F[0, :, 0], F[0, :, 1], F[0, :, 2], s=6, c="tab:red", depthshade=False)
    lo, hi = F.reshape(-1, 3).min(0), F.reshape(-1, 3).max(0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, m in zip((ax3.set_xlim, ax3.set_ylim, ax3.set_zlim), mid, strict=True):
        setter(m - half, m + half)
    ax3.view_init(elev=8, azim=-75)
    ax3.set_axis_off()
    label = ax3.text2D(0.02, 0.95, "", transform=ax3.transAxes, fontsize=8)

    def update(k):
        i = sel[k]
        cross.set_data([pxy[i, 0]], [pxy[i, 1]])
        lines.set_segments(F[i][edges])
        dots._offsets3d = (F[i, :, 0], F[i, :, 1], F[i, :, 2])
        label.set_text(f"t = {play.times[i]:.2f} s, frame {int(play.frame[i])}")
        return cross, lines, dots, label

    anim = animation.FuncAnimation(fig, update, frames=len(sel), blit=False)
    fps = float(play.fps) * len(sel) / max(K, 1)
    import os
    import tempfile

    fd, tmp_name = tempfile.mkstemp(prefix=".fx", suffix=path.suffix, dir=path.parent)
    os.close(fd)  # a unique short temp name beside the target (never NAME.tmp)
    tmp = Path(tmp_name)
    try:
        if path.suffix == ".mp4":
            anim.save(tmp, writer=animation.FFMpegWriter(fps=fps), dpi=dpi)
        else:
            anim.save(tmp, writer=animation.PillowWriter(fps=max(1.0, fps)), dpi=dpi)
        write_bytes_atomic(path, tmp.read_bytes())
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
    return path
