"""Mesh IK experiment: Park, Kang & Kwon §5 (Figs. 4–10), on every mesh of the config.

For each mesh (``"File:animation"``, file stem under ``mesh/``) and each marker count
(1 / 5 / 10 / 50 / 120 by default): markers on random triangles visible from a random
viewpoint (seeded), targets from ``num_frames`` frames of the mesh's own animation (300,
as the paper), and IK solved frame by frame, one jitted call per frame:

- from the rest pose every frame (**cold**, as the paper) and from the previous frame's
  pose (**warm**);
- with Levenberg–Marquardt on the analytic Jacobian (the library's default) and with
  BFGS driven by the factored gradient (eq. (13)) and by the naive one (eq. (9)) — the
  paper's comparison: both BFGS runs take identical steps, so their time ratio is what
  eq. (13) buys per solved frame. The naive run is timed on ``naive_frames`` evenly
  spaced frames, each started where the factored run started it (the same solves), to
  keep the experiment to minutes; the bare gradient evaluations are timed too.

Metrics per mesh × markers: mean time per frame, vertex error against the true posed
mesh, marker residual, naive/factored ratios (``metrics.json`` and ``table.md``).
Figures: ``<mesh>_poses.png`` (rest / target / deformed, shaded: Figs. 4–8),
``<mesh>_time_per_frame.png`` (naive vs factored per frame at the largest count: Fig. 9),
``<mesh>_time_vs_markers.png`` (Fig. 10), ``<mesh>_error_vs_markers.png``, and
``regularizers.png`` (vertex error with few markers with and without the optional
joint-angle prior, joint limits and normal constraint).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress, stage
from fxspace.mesh import (
    BFGS,
    Pose,
    ancestor_table,
    constraints_from_regularization,
    ik_model,
    ik_regularization,
    marker_positions,
    place_markers,
    pose_vertices,
    track_ik,
    triangle_normals,
    visible_triangles,
)
from fxspace.pipelines._mesh_ik_config import PAPER as PAPER
from fxspace.pipelines._mesh_ik_config import SOLVERS as SOLVERS
from fxspace.pipelines._mesh_ik_config import Config as Config
from fxspace.pipelines._mesh_ik_config import _parse_spec as _parse_spec
from fxspace.pipelines._mesh_ik_report import _figures as _figures
from fxspace.pipelines._mesh_ik_report import _models as _models
from fxspace.pipelines._mesh_ik_report import _paper_comparison as _paper_comparison
from fxspace.pipelines._mesh_ik_report import _table as _table
from fxspace.pipelines._mesh_ik_solve import _cast as _cast
from fxspace.pipelines._mesh_ik_solve import _frame as _frame
from fxspace.pipelines._mesh_ik_solve import _gradient_us as _gradient_us
from fxspace.pipelines._mesh_ik_solve import _load as _load
from fxspace.pipelines._mesh_ik_solve import _per_frame as _per_frame
from fxspace.pipelines._mesh_ik_solve import _per_frame_replay as _per_frame_replay
from fxspace.pipelines._mesh_ik_solve import _solver_opts as _solver_opts
from fxspace.pipelines._mesh_ik_solve import median_time as median_time
from fxspace.pipelines._mesh_ik_solve import random_view as random_view
from fxspace.runs import cached, save_figure_atomic, save_npz_atomic, write_text_atomic

__all__ = ["Config", "STAGES", "run", "median_time", "random_view"]

STAGES: tuple[str, ...] = ("per_mesh", "regularizers")
APP = "fxspace.studio._ik:serve_ik"  # `fxspace studio`: the IK studio ...
REPRODUCTION = "park-kang-kwon"  # its reproduction page (`fxspace docs`)
APP_OPENS_CONFIG = True  # ... built from the config (one mesh), no run first
"""The costly stages, in order: ``per_mesh`` (every solver and start along the frames, per
mesh and marker count; cached per mesh as ``cache/per_mesh_<mesh>.json``) and
``regularizers`` (few markers with and without the constraints)."""


def _run_mesh(cfg: Config, spec: str, run_dir: Path, seed: int, label: str = "") -> dict:
    dtype = jnp.float64 if cfg.dtype == "float64" else jnp.float32
    stage(f"{label}loading {spec} ({cfg.num_frames} frames)")
    stem, mesh, anim, truth = _load(spec, cfg.num_frames, dtype)
    rng = np.random.default_rng(seed)
    view = (
        np.asarray(cfg.view_dir, float)
        if cfg.view_dir
        else random_view(mesh.vertices, mesh.faces, max(cfg.marker_counts), rng)
    )
    n_vis = int(np.asarray(visible_triangles(mesh.vertices, mesh.faces, view)).sum())
    scale = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    posed = jax.jit(jax.vmap(lambda p: pose_vertices(mesh, p)))
    fig_frame = int(round(cfg.figure_frame * (cfg.num_frames - 1)))
    rest = Pose(jnp.zeros((mesh.num_joints, 3), dtype), jnp.zeros((3,), dtype))
    out: dict = {
        "mesh": stem,
        "animation": anim,
        "joints": mesh.num_joints,
        "depth": int(ancestor_table(mesh.parents).shape[1]),
        "vertices": mesh.num_vertices,
        "triangles": int(mesh.faces.shape[0]),
        "visible_triangles": n_vis,
        "view_dir": view.tolist(),
        "frames": cfg.num_frames,
        "scale": scale,
        "per_markers": {},
    }
    figure_rows, series = {}, {}
    counts = [k for k in cfg.marker_counts if k <= n_vis]
    for j, k in enumerate(progress(counts, desc=f"{label}{stem}: marker counts")):
        stage(f"{label}{stem}: {k} markers ({j + 1}/{len(counts)} marker counts)")
        ms = place_markers(mesh.vertices, mesh.faces, k, view, seed=rng)
        model = _cast(ik_model(mesh, ms), dtype)
        targets = marker_positions(truth, mesh.faces, ms).astype(dtype)  # (T, K, 3)
        row: dict = {"markers": k}
        frames = np.unique(np.linspace(0, cfg.num_frames - 1, cfg.naive_frames).astype(int))
        for solver in SOLVERS[:2]:
            for start in cfg.starts:
                ts, res = _per_frame(model, targets, rest, start, **_solver_opts(cfg, solver))
                verr = jnp.linalg.norm(posed(res.pose) - truth, axis=-1)  # (T, V)
                key = f"{solver}_{start}"
                row[f"{key}_ms_mean"] = 1e3 * float(np.mean(ts))
                row[f"{key}_ms_median"] = 1e3 * float(np.median(ts))
                row[f"{key}_vertex_error"] = float(jnp.mean(verr))
                row[f"{key}_marker_rms"] = float(jnp.mean(res.residual))
                row[f"{key}_steps"] = float(jnp.mean(res.num_steps))
                row[f"{key}_converged"] = float(jnp.mean(res.converged))
                if solver == "bfgs_factored":
                    tn, dev = _per_frame_replay(
                        model,
                        targets,
                        rest,
                        start,
                        frames,
                        res.pose,
                        **_solver_opts(cfg, "bfgs_naive"),
                    )
                    row[f"bfgs_naive_{start}_ms_mean"] = 1e3 * float(np.mean(tn))
                    row[f"bfgs_naive_{start}_ms_median"] = 1e3 * float(np.median(tn))
                    row[f"bfgs_naive_{start}_max_angle_difference"] = dev
                    row[f"ratio_naive_factored_{start}"] = float(np.mean(tn) / np.mean(ts[frames]))
                    if k == max(counts):
                        series[f"factored ({start})"] = 1e3 * ts[frames]
                        series[f"naive ({start})"] = 1e3 * tn
                if solver == "lm" and start == cfg.starts[0]:
                    figure_rows[k] = (
                        np.asarray(pose_vertices(mesh, _frame(res.pose, fig_frame))),
                        np.asarray(targets[fig_frame]),
                        np.asarray(marker_positions(jnp.asarray(mesh.vertices), mesh.faces, ms)),
                    )
                    save_npz_atomic(
                        run_dir / f"{stem}_{k}_markers.npz",
                        angles=np.asarray(res.pose.angles),
                        translation=np.asarray(res.pose.translation),
                        vertex_error=np.asarray(verr.mean(axis=1)),
                        triangles=np.asarray(ms.triangles),
                        barycentric=np.asarray(ms.barycentric),
                    )
        g = _gradient_us(model, rest, targets[fig_frame], cfg.gradient_repeats)
        row["gradient_us_naive"], row["gradient_us_factored"] = g["call_naive"], g["call_factored"]
        row["gradient_loop_us_naive"] = g["loop_naive"]
        row["gradient_loop_us_factored"] = g["loop_factored"]
        row["ratio_naive_factored_gradient"] = g["call_naive"] / g["call_factored"]
        row["ratio_naive_factored_gradient_loop"] = g["loop_naive"] / g["loop_factored"]
        out["per_markers"][str(k)] = row
    out["skipped_marker_counts"] = [k for k in cfg.marker_counts if k > n_vis]
    _figures(
        cfg, mesh, stem, anim, truth, fig_frame, view, counts, out, figure_rows, series, run_dir
    )
    return out


def _run_regularizers(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Vertex error with few markers, with and without each regulariser (warm tracking)."""
    from fxspace.plot import plot_vs_markers

    dtype = jnp.float64 if cfg.dtype == "float64" else jnp.float32
    stem, mesh, anim, truth = _load(cfg.reg_mesh, cfg.num_frames, dtype)
    rng = np.random.default_rng(seed + 7)
    view = (
        np.asarray(cfg.view_dir, float)
        if cfg.view_dir
        else random_view(mesh.vertices, mesh.faces, max(cfg.reg_marker_counts), rng)
    )
    posed = jax.jit(jax.vmap(lambda p: pose_vertices(mesh, p)))
    variants = {
        "none": {},
        "joint prior": dict(prior=cfg.reg_prior, prior_to=cfg.reg_prior_to),
        "joint limits": dict(limits=cfg.reg_limits, limit=cfg.reg_limit),
        "normals": dict(normal=cfg.reg_normal),
        "all": dict(
            prior=cfg.reg_prior,
            prior_to=cfg.reg_prior_to,
            limits=cfg.reg_limits,
            limit=cfg.reg_limit,
            normal=cfg.reg_normal,
        ),
    }
    errs: dict[str, list[float]] = {v: [] for v in variants}
    counts = list(cfg.reg_marker_counts)
    stage(f"regularisers on {stem}: {len(counts)} marker counts × {len(variants)} variants")
    for k in progress(counts, desc=f"{stem}: regularisers"):
        ms = place_markers(mesh.vertices, mesh.faces, k, view, seed=rng)
        model = _cast(ik_model(mesh, ms), dtype)
        targets = marker_positions(truth, mesh.faces, ms).astype(dtype)
        nrm = jax.vmap(lambda v: triangle_normals(v, mesh.faces))(truth)[:, ms.triangles]
        nrm = nrm / jnp.linalg.norm(nrm, axis=-1, keepdims=True)
        for name, w in variants.items():
            reg = ik_regularization(model, mesh=mesh, markers=ms, **w) if w else None
            kw = dict(solver=BFGS(rtol=cfg.bfgs_rtol, max_steps=cfg.bfgs_steps))
            if reg is not None and reg.corners is not None:
                kw["target_normals"] = nrm.astype(dtype)
            cons = None if reg is None else constraints_from_regularization(reg)
            tr = track_ik(model, targets, constraints=cons, **kw)
            verr = jnp.linalg.norm(posed(tr.pose) - truth, axis=-1)
            errs[name].append(float(jnp.mean(verr)))
    save_figure_atomic(
        plot_vs_markers(
            counts,
            errs,
            "mean vertex error [mesh units]",
            title=f"{stem}: few markers, with and without regularisers",
        ),
        run_dir / "regularizers.png",
    )
    return {"mesh": stem, "animation": anim, "marker_counts": counts, "vertex_error": errs}


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    run_dir = Path(run_dir)
    with jax.enable_x64(cfg.dtype == "float64"):
        results = {}
        for i, spec in enumerate(cfg.meshes):
            label = f"mesh {i + 1}/{len(cfg.meshes)} "
            key = "per_mesh_" + "".join(c if c.isalnum() else "_" for c in spec)
            r = cached(run_dir, key, partial(_run_mesh, cfg, spec, run_dir, seed, label))
            results[r["mesh"]] = r
            rows = r["per_markers"]
            kmax = max(rows, key=int)
            row = rows[kmax]
            for st in cfg.starts:
                print(
                    f"[mesh_ik] {r['mesh']}: {kmax} markers ({st}): LM "
                    f"{row[f'lm_{st}_ms_mean']:.2f} ms/frame, BFGS factored "
                    f"{row[f'bfgs_factored_{st}_ms_mean']:.2f} / naive "
                    f"{row[f'bfgs_naive_{st}_ms_mean']:.2f} ms = "
                    f"{row[f'ratio_naive_factored_{st}']:.2f}x; gradient "
                    f"{row['ratio_naive_factored_gradient_loop']:.2f}x in a loop, "
                    f"{row['ratio_naive_factored_gradient']:.2f}x per call; vertex error LM by "
                    "markers "
                    + ", ".join(f"{k}: {v[f'lm_{st}_vertex_error']:.3g}" for k, v in rows.items())
                )
        reg = None
        if cfg.reg_marker_counts:
            reg = cached(run_dir, "regularizers", partial(_run_regularizers, cfg, run_dir, seed))
    models = _models(results, cfg.starts, run_dir)
    write_text_atomic(run_dir / "table.md", _table(results, cfg.starts) + models["table"])
    return {
        "meshes": results,
        "paper_comparison": _paper_comparison(results, cfg.starts),
        "models": models["ratios"],
        "regularizers": reg,
        "paper": PAPER,
        "dtype": cfg.dtype,
        "device": str(jax.devices()[0]),
    }
