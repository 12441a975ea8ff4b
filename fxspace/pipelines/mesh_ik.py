"""Mesh IK experiment (issue 6; Park, Kang & Kwon, §4).

For each mesh and each marker count (1 / 5 / 10 / 50 / 120 by default): markers on the
triangles facing the camera, targets from an animation's frames (300 by default, as in
the paper), IK solved frame by frame from the rest pose, each frame warm-started from the
previous one. Reports the marker residual, the vertex error against the true posed mesh,
the time per frame of the Levenberg–Marquardt solve, and the time per frame of a
first-order (Adam) solve with each of the three gradients (naive eq. (9), factored
eq. (13), autodiff), plus the bare gradient times. Figures: rest / target / deformed per
marker count, time per frame naive vs factored, time and vertex error vs markers.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.mesh._ik import (
    GRADIENTS,
    ik_gradient_factored,
    ik_gradient_naive,
    ik_model,
    solve_ik,
    track_ik,
)
from fxspace.mesh._ik import ik_gradient_autodiff as _autodiff
from fxspace.mesh._markers import marker_positions, place_markers
from fxspace.mesh._skinning import Pose, pose_vertices
from fxspace.runs import save_figure_atomic, save_npz_atomic

__all__ = ["Config", "run", "median_time"]

PAPER = {"accelerated_ms": 32.5, "naive_ms": 90.6, "speedup_mean": 3.14, "speedup_human": 2.78}


@dataclasses.dataclass(frozen=True)
class Config:
    """``meshes``: ``"File:animation"`` (file stem under ``mesh/``; empty animation = the
    first). ``view_dir``: the camera's viewing direction for marker placement."""

    meshes: tuple[str, ...] = ("CesiumMan:Anim_0", "Fox:Walk")
    marker_counts: tuple[int, ...] = (1, 5, 10, 50, 120)
    num_frames: int = 300
    view_dir: tuple[float, ...] = (0.0, 0.0, -1.0)
    max_steps: int = 50
    lm_rtol: float = 1e-3
    adam_steps: int = 20
    adam_learning_rate: float = 0.01
    timing_frames: int = 60
    timing_repeats: int = 3
    figure_frame: float = 0.5  # which frame (fraction of the animation) the pose figure shows
    dtype: Literal["float32", "float64"] = "float64"

    def validate(self) -> None:
        if not self.meshes:
            raise ConfigError("meshes must name at least one mesh, e.g. 'CesiumMan:Anim_0'")
        if not self.marker_counts or min(self.marker_counts) < 1:
            raise ConfigError("marker_counts must be positive integers")
        if len(self.view_dir) != 3:
            raise ConfigError("view_dir must have 3 components")
        if self.num_frames < 2 or self.timing_frames < 1 or self.timing_repeats < 1:
            raise ConfigError("num_frames >= 2, timing_frames >= 1, timing_repeats >= 1 please")
        if not 0.0 <= self.figure_frame <= 1.0:
            raise ConfigError("figure_frame is a fraction of the animation in [0, 1]")


def median_time(fn, repeats: int) -> tuple[float, float]:
    """(median, min) wall time in seconds of ``fn()`` over ``repeats`` calls (already compiled)."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def _per_frame_times(model, targets, n, **kw) -> np.ndarray:
    """Seconds per frame of jitted warm-started ``solve_ik`` calls, frame by frame."""
    nj = model.ancestors.shape[0]
    pose = Pose(jnp.zeros((nj, 3), targets.dtype), jnp.zeros((3,), targets.dtype))
    jax.block_until_ready(solve_ik(model, targets[0], pose, **kw))  # compile
    out = np.empty(n)
    for t in range(n):
        t0 = time.perf_counter()
        res = solve_ik(model, targets[t], pose, **kw)
        jax.block_until_ready(res)
        out[t] = time.perf_counter() - t0
        pose = res.pose
    return out


def _run_mesh(cfg: Config, spec: str, run_dir: Path, seed: int) -> dict:
    from fxspace.io import read_gltf

    stem, _, anim = spec.partition(":")
    mesh = read_gltf(data_path("mesh", f"{stem}.glb"))
    anim = anim or mesh.animation_names[0]
    t0, t1 = mesh.animation_range(anim)
    times = np.linspace(t0, t1, cfg.num_frames)
    dtype = jnp.float64 if cfg.dtype == "float64" else jnp.float32
    truth = jnp.asarray(mesh.animation_vertices(anim, times), dtype)  # (T, V, 3)
    scale = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    posed = jax.jit(jax.vmap(lambda p: pose_vertices(mesh, p)))
    fig_frame = int(round(cfg.figure_frame * (cfg.num_frames - 1)))
    nt = min(cfg.timing_frames, cfg.num_frames)
    out: dict = {
        "mesh": stem,
        "animation": anim,
        "joints": mesh.num_joints,
        "vertices": mesh.num_vertices,
        "frames": cfg.num_frames,
        "scale": scale,
        "per_markers": {},
    }
    figure_rows = {}
    per_frame_series = {}
    for k in progress(cfg.marker_counts, desc=f"{stem} marker counts"):
        rng = np.random.default_rng(seed + 1000 * k)
        ms = place_markers(mesh.vertices, mesh.faces, k, cfg.view_dir, seed=rng)
        model = jax.tree_util.tree_map(
            lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a,
            ik_model(mesh, ms),
        )
        targets = marker_positions(truth, mesh.faces, ms).astype(dtype)  # (T, K, 3)
        opts = dict(method="lm", max_steps=cfg.max_steps, rtol=cfg.lm_rtol)
        tr = jax.block_until_ready(track_ik(model, targets, **opts))
        scan_s, _ = median_time(
            lambda m=model, t=targets, o=opts: track_ik(m, t, **o), cfg.timing_repeats
        )
        verts = posed(tr.pose)
        verr = jnp.linalg.norm(verts - truth, axis=-1)  # (T, V)
        lm_frames = _per_frame_times(model, targets, nt, **opts)
        row = {
            "markers": k,
            "marker_rms_mean": float(jnp.mean(tr.residual)),
            "marker_rms_max": float(jnp.max(tr.residual)),
            "vertex_error_mean": float(jnp.mean(verr)),
            "vertex_error_max": float(jnp.max(verr)),
            "vertex_error_mean_rel": float(jnp.mean(verr)) / scale,
            "converged_fraction": float(jnp.mean(tr.converged)),
            "lm_steps_mean": float(jnp.mean(tr.num_steps)),
            "lm_ms_per_frame_scan": 1e3 * scan_s / cfg.num_frames,
            "lm_ms_per_frame_call_median": 1e3 * float(np.median(lm_frames)),
            "lm_ms_per_frame_call_mean": 1e3 * float(np.mean(lm_frames)),
        }
        # bare gradient at the rest pose against the middle frame's targets (forward + gradient)
        rest = Pose(jnp.zeros((mesh.num_joints, 3), dtype), jnp.zeros((3,), dtype))
        fns = {"naive": ik_gradient_naive, "factored": ik_gradient_factored, "autodiff": _autodiff}
        for name in GRADIENTS:
            f = jax.jit(fns[name])
            jax.block_until_ready(f(model, rest, targets[fig_frame]))
            reps = 200
            med, _ = median_time(
                lambda f=f, a=(model, rest, targets[fig_frame]), n=reps: [f(*a) for _ in range(n)][
                    -1
                ],
                max(cfg.timing_repeats, 3),
            )
            row[f"gradient_us_{name}"] = 1e6 * med / reps
            # first-order solve per frame with this gradient (fixed step count: atol=0)
            adam = dict(
                method="adam",
                gradient=name,
                max_steps=cfg.adam_steps,
                atol=0.0,
                learning_rate=cfg.adam_learning_rate,
            )
            ft = _per_frame_times(model, targets, nt, **adam)
            row[f"adam_ms_per_frame_{name}"] = 1e3 * float(np.median(ft))
            if k == max(cfg.marker_counts):
                per_frame_series[name] = 1e3 * ft
        row["gradient_speedup_factored_vs_naive"] = (
            row["gradient_us_naive"] / row["gradient_us_factored"]
        )
        row["adam_speedup_factored_vs_naive"] = (
            row["adam_ms_per_frame_naive"] / row["adam_ms_per_frame_factored"]
        )
        out["per_markers"][str(k)] = row
        figure_rows[k] = (
            np.asarray(verts[fig_frame]),
            np.asarray(targets[fig_frame]),
            np.asarray(marker_positions(jnp.asarray(mesh.vertices, dtype), mesh.faces, ms)),
        )
        save_npz_atomic(
            run_dir / f"{stem}_{k}_markers.npz",
            angles=np.asarray(tr.pose.angles),
            translation=np.asarray(tr.pose.translation),
            residual=np.asarray(tr.residual),
            vertex_error=np.asarray(verr.mean(axis=1)),
            triangles=np.asarray(ms.triangles),
            barycentric=np.asarray(ms.barycentric),
        )

    from fxspace.plot import plot_ik_poses, plot_time_per_frame, plot_vs_markers

    counts = list(cfg.marker_counts)
    rows = [out["per_markers"][str(k)] for k in counts]
    save_figure_atomic(
        plot_ik_poses(
            mesh.faces,
            mesh.vertices,
            np.asarray(truth[fig_frame]),
            figure_rows,
            title=f"{stem} / {anim}, frame {fig_frame}",
            axes2d=(0 if np.ptp(mesh.vertices[:, 0]) >= np.ptp(mesh.vertices[:, 2]) else 2, 1),
        ),
        run_dir / f"{stem}_poses.png",
    )
    save_figure_atomic(
        plot_time_per_frame(
            per_frame_series,
            title=f"{stem}: Adam, {cfg.adam_steps} steps/frame, {max(counts)} markers",
        ),
        run_dir / f"{stem}_time_per_frame.png",
    )
    save_figure_atomic(
        plot_vs_markers(
            counts,
            {g: [r[f"adam_ms_per_frame_{g}"] for r in rows] for g in GRADIENTS}
            | {"LM (analytic J)": [r["lm_ms_per_frame_call_median"] for r in rows]},
            "time per frame [ms]",
            title=f"{stem}: average time per frame",
        ),
        run_dir / f"{stem}_time_vs_markers.png",
    )
    save_figure_atomic(
        plot_vs_markers(
            counts,
            {
                "mean vertex error": [r["vertex_error_mean"] for r in rows],
                "marker RMS residual": [r["marker_rms_mean"] for r in rows],
            },
            "distance [mesh units]",
            title=f"{stem}: error vs markers",
            logy=True,
        ),
        run_dir / f"{stem}_error_vs_markers.png",
    )
    errs = [r["vertex_error_mean"] for r in rows]
    out["vertex_error_decreasing"] = bool(errs[-1] < errs[0])
    return out


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    run_dir = Path(run_dir)
    with jax.enable_x64(cfg.dtype == "float64"):
        results = {}
        for spec in cfg.meshes:
            r = _run_mesh(cfg, spec, run_dir, seed)
            results[r["mesh"]] = r
            kmax = str(max(cfg.marker_counts))
            row = r["per_markers"][kmax]
            print(
                f"[mesh_ik] {r['mesh']}: {kmax} markers: LM "
                f"{row['lm_ms_per_frame_call_median']:.2f} ms/frame, vertex error "
                f"{row['vertex_error_mean']:.4g} (mean), gradient naive "
                f"{row['gradient_us_naive']:.0f} us / factored {row['gradient_us_factored']:.0f} us"
                f" = {row['gradient_speedup_factored_vs_naive']:.2f}x; vertex error by markers "
                + ", ".join(
                    f"{k}: {r['per_markers'][str(k)]['vertex_error_mean']:.3g}"
                    for k in cfg.marker_counts
                )
            )
    return {"meshes": results, "paper": PAPER, "dtype": cfg.dtype, "device": str(jax.devices()[0])}
