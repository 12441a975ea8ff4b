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

import dataclasses
import time
from functools import partial
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress, stage
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.mesh import (
    BFGS,
    LevenbergMarquardt,
    Pose,
    ancestor_table,
    animation_vertices,
    chain_mesh,
    constraints_from_regularization,
    ik_gradient_factored,
    ik_gradient_naive,
    ik_model,
    ik_regularization,
    marker_positions,
    place_markers,
    pose_vertices,
    solve_ik,
    subdivide_mesh,
    track_ik,
    triangle_normals,
    visible_triangles,
)
from fxspace.runs import cached, save_figure_atomic, save_npz_atomic, write_text_atomic

__all__ = ["Config", "STAGES", "run", "median_time", "random_view"]

STAGES: tuple[str, ...] = ("per_mesh", "regularizers")
APP = "fxspace.studio._ik:serve_ik"  # `fxspace studio`: the IK studio ...
APP_OPENS_CONFIG = True  # ... built from the config (one mesh), no run first
"""The costly stages, in order: ``per_mesh`` (every solver and start along the frames, per
mesh and marker count; cached per mesh as ``cache/per_mesh_<mesh>.json``) and
``regularizers`` (few markers with and without the constraints)."""

PAPER = {"accelerated_ms": 32.5, "naive_ms": 90.6, "speedup_mean": 3.14, "speedup_human": 2.78}
SOLVERS = (
    "lm",
    "bfgs_factored",
    "bfgs_naive",
)  # the naive run replays frames (see _per_frame_replay)


@dataclasses.dataclass(frozen=True)
class Config:
    """``meshes``: ``"File:animation"`` (file stem under ``mesh/``; empty animation = the
    first); ``"File+N:animation"`` is that mesh subdivided to ``N`` vertices
    (`fxspace.mesh.subdivide_mesh`, e.g. CesiumMan at the paper's 13.8k), ``"chainN:wave"``
    a procedural chain of ``N`` joints (`fxspace.mesh.chain_mesh`).
    ``view_dir``: the camera's viewing direction for marker placement; empty =
    a random viewpoint (seeded) with enough visible triangles. ``reg_*``: the regulariser
    weights of the comparison (``fxspace.mesh.ik_regularization``)."""

    meshes: tuple[str, ...] = (
        "CesiumMan:Anim_0",
        "Fox:Walk",
        "RiggedSimple:",
        "CesiumMan+13800:Anim_0",
        "chain48:wave",
    )
    marker_counts: tuple[int, ...] = (1, 5, 10, 50, 120)
    num_frames: int = 300
    view_dir: tuple[float, ...] = ()
    lm_rtol: float = 1e-3
    lm_steps: int = 50
    bfgs_rtol: float = 1e-3
    bfgs_steps: int = 200
    naive_frames: int = 60  # frames (evenly spaced) the naive-gradient BFGS is timed on
    starts: tuple[str, ...] = ("cold", "warm")
    gradient_repeats: int = 3
    figure_frame: float = 0.5  # which frame (fraction of the animation) the pose figure shows
    reg_mesh: str = "CesiumMan:Anim_0"
    reg_marker_counts: tuple[int, ...] = (1, 5, 10)
    reg_prior: float = 1e-3
    reg_prior_to: Literal["rest", "previous"] = "previous"
    reg_limits: float = 1.0
    reg_limit: float = 1.5707963267948966
    reg_normal: float = 1e-2
    dtype: Literal["float32", "float64"] = "float64"

    def validate(self) -> None:
        if not self.meshes:
            raise ConfigError("meshes must name at least one mesh, e.g. 'CesiumMan:Anim_0'")
        for spec in self.meshes:
            _parse_spec(spec)
        if not self.marker_counts or min(self.marker_counts) < 1:
            raise ConfigError("marker_counts must be positive integers")
        if self.view_dir and (len(self.view_dir) != 3 or not any(self.view_dir)):
            raise ConfigError("view_dir must be empty (random) or a non-zero 3-vector")
        if self.num_frames < 2 or self.gradient_repeats < 1 or self.naive_frames < 1:
            raise ConfigError("num_frames >= 2, naive_frames >= 1, gradient_repeats >= 1 please")
        if not set(self.starts) <= {"cold", "warm"} or not self.starts:
            raise ConfigError("starts must be a non-empty subset of ['cold', 'warm']")
        if not 0.0 <= self.figure_frame <= 1.0:
            raise ConfigError("figure_frame is a fraction of the animation in [0, 1]")
        for name in ("reg_prior", "reg_limits", "reg_normal", "lm_rtol", "bfgs_rtol"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0")
        if self.reg_prior_to not in ("rest", "previous"):
            raise ConfigError("reg_prior_to must be 'rest' or 'previous'")


def _parse_spec(spec: str) -> tuple[str, int, str]:
    """``(kind, n, animation)`` of a mesh spec: kind ``"chain"`` (n joints) or a file stem
    (n = vertices to subdivide to, 0 = as read)."""
    stem, _, anim = str(spec).partition(":")
    if stem.startswith("chain"):
        n = stem[5:] or "48"
        if not n.isdigit() or int(n) < 2:
            raise ConfigError(f"meshes: {spec!r}: a chain is 'chainN' with N >= 2 joints")
        return "chain", int(n), anim
    base, plus, n = stem.partition("+")
    if not base or (plus and (not n.isdigit() or int(n) < 1)):
        raise ConfigError(f"meshes: {spec!r} is not 'File:anim', 'File+N:anim' or 'chainN:anim'")
    return base, int(n) if plus else 0, anim


def median_time(fn, repeats: int) -> tuple[float, float]:
    """(median, min) wall time in seconds of ``fn()`` over ``repeats`` calls (already compiled)."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def random_view(vertices, faces, need: int, rng: np.random.Generator) -> np.ndarray:
    """A random unit viewing direction from which at least ``need`` triangles face the
    camera (the one with the most, after 16 tries, when none has enough)."""
    best, best_n = None, -1
    for _ in range(16):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        n = int(np.asarray(visible_triangles(vertices, faces, d)).sum())
        if n >= need:
            return d
        if n > best_n:
            best, best_n = d, n
    return best


def _solver_opts(cfg: Config, name: str) -> dict:
    if name == "lm":
        return dict(solver=LevenbergMarquardt(rtol=cfg.lm_rtol, max_steps=cfg.lm_steps))
    grad = name.split("_", 1)[1]
    return dict(solver=BFGS(rtol=cfg.bfgs_rtol, max_steps=cfg.bfgs_steps, gradient=grad))


def _per_frame(model, targets, rest, start: str, **kw):
    """Seconds per frame of jitted ``solve_ik`` calls along the frames, and the results."""
    jax.block_until_ready(solve_ik(model, targets[0], rest, **kw))  # compile
    n = targets.shape[0]
    times = np.empty(n)
    out = []
    pose = rest
    for t in range(n):
        t0 = time.perf_counter()
        res = jax.block_until_ready(solve_ik(model, targets[t], pose, **kw))
        times[t] = time.perf_counter() - t0
        out.append(res)
        if start == "warm":
            pose = res.pose
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *out)
    return times, stacked


def _per_frame_replay(model, targets, rest, start, frames, poses, **kw):
    """Per-frame times on ``frames`` only, each started where the full run started it (rest,
    or the given run's pose of the frame before): the same solves as that run's, so a
    solver taking identical steps (naive vs factored gradient) is timed like for like."""
    jax.block_until_ready(solve_ik(model, targets[0], rest, **kw))  # compile
    times = np.empty(len(frames))
    dev = 0.0
    for i, t in enumerate(frames):
        init = rest if start == "cold" or t == 0 else _frame(poses, t - 1)
        t0 = time.perf_counter()
        res = jax.block_until_ready(solve_ik(model, targets[t], init, **kw))
        times[i] = time.perf_counter() - t0
        dev = max(dev, float(jnp.max(jnp.abs(res.pose.angles - poses.angles[t]))))
    return times, dev


def _gradient_us(model, pose, targets, repeats: int, loop: int = 100) -> dict:
    """Microseconds per gradient evaluation (forward pass + gradient), per form:

    - ``call``: one jitted call per evaluation with the model bound into the function
      (``jax.jit(partial(grad, model))``, as an interactive solver holds it), 200 calls;
    - ``loop``: ``loop`` evaluations inside one jitted loop (how the solvers call it; each
      pose moved by ``-1e-9 ∇E`` so none can be hoisted), no per-call cost.
    """
    out = {}
    for name, g in (("naive", ik_gradient_naive), ("factored", ik_gradient_factored)):
        f = jax.jit(partial(g, model))

        def body(_, q, g=g):
            d = g(model, q, targets)
            return jax.tree_util.tree_map(lambda a, b: a - 1e-9 * b, q, d)

        in_loop = jax.jit(lambda p, body=body: jax.lax.fori_loop(0, loop, body, p))
        jax.block_until_ready((f(pose, targets), in_loop(pose)))
        med, _ = median_time(lambda f=f: [f(pose, targets) for _ in range(200)][-1], repeats)
        out[f"call_{name}"] = 1e6 * med / 200
        med, _ = median_time(lambda in_loop=in_loop: in_loop(pose), repeats)
        out[f"loop_{name}"] = 1e6 * med / loop
    return out


def _load(spec: str, num_frames: int, dtype):
    from fxspace.io import read_gltf

    kind, n, anim = _parse_spec(spec)
    if kind == "chain":
        mesh, stem = chain_mesh(n), f"chain{n}"
    else:
        mesh, stem = read_gltf(data_path("mesh", f"{kind}.glb")), kind
        if n:
            mesh, stem = subdivide_mesh(mesh, num_vertices=n), f"{kind}+{n}"
    anim = anim or mesh.animation_names[0]
    times = np.linspace(*mesh.animation_range(anim), num_frames)
    truth = jnp.asarray(animation_vertices(mesh, anim, times), dtype)  # (T, V, 3)
    return stem, mesh, anim, truth


def _frame(pose: Pose, t: int) -> Pose:
    return Pose(pose.angles[t], pose.translation[t])


def _cast(model, dtype):
    return jax.tree_util.tree_map(
        lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, model
    )


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


def _figures(cfg, mesh, stem, anim, truth, fig_frame, view, counts, out, rows_fig, series, run_dir):
    from fxspace.plot import plot_ik_poses, plot_time_per_frame, plot_vs_markers

    rows = [out["per_markers"][str(k)] for k in counts]
    save_figure_atomic(
        plot_ik_poses(
            mesh.faces,
            mesh.vertices,
            np.asarray(truth[fig_frame]),
            rows_fig,
            title=f"{stem} / {anim}, frame {fig_frame} (LM, {cfg.starts[0]} start)",
            view_dir=view,
        ),
        run_dir / f"{stem}_poses.png",
    )
    save_figure_atomic(
        plot_time_per_frame(
            series,
            title=f"{stem}: BFGS per frame, {max(counts)} markers, naive vs factored "
            f"({len(series) and cfg.naive_frames} timed frames)",
        ),
        run_dir / f"{stem}_time_per_frame.png",
    )
    times = {}
    for s in SOLVERS:
        for st in cfg.starts:
            times[f"{s.replace('_', ' ')} ({st})"] = [r[f"{s}_{st}_ms_mean"] for r in rows]
    # naive mean over its timed frames; factored over all frames (see the table for like-for-like)
    save_figure_atomic(
        plot_vs_markers(
            counts,
            times,
            "mean time per frame [ms]",
            title=f"{stem}: mean time per frame",
            logy=True,
        ),
        run_dir / f"{stem}_time_vs_markers.png",
    )
    errs = {}
    for s in ("lm", "bfgs_factored"):
        for st in cfg.starts:
            errs[f"{s.replace('_', ' ')} ({st})"] = [r[f"{s}_{st}_vertex_error"] for r in rows]
    save_figure_atomic(
        plot_vs_markers(
            counts,
            errs,
            "mean vertex error [mesh units]",
            title=f"{stem}: vertex error vs markers",
            logy=True,
        ),
        run_dir / f"{stem}_error_vs_markers.png",
    )


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


def _table(results: dict, starts) -> str:
    lines = [
        "| mesh | markers | start | LM ms/frame | BFGS factored ms | BFGS naive ms | "
        "naive/factored per frame | naive/factored per gradient (in loop / one call) | "
        "vertex error LM | vertex error BFGS | marker RMS LM | LM converged |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        for k, row in r["per_markers"].items():
            for st in starts:
                lines.append(
                    f"| {name} | {k} | {st} | {row[f'lm_{st}_ms_mean']:.2f} | "
                    f"{row[f'bfgs_factored_{st}_ms_mean']:.2f} | "
                    f"{row[f'bfgs_naive_{st}_ms_mean']:.2f} | "
                    f"{row[f'ratio_naive_factored_{st}']:.2f}x | "
                    f"{row['ratio_naive_factored_gradient_loop']:.2f}x / "
                    f"{row['ratio_naive_factored_gradient']:.2f}x | "
                    f"{row[f'lm_{st}_vertex_error']:.3g} | "
                    f"{row[f'bfgs_factored_{st}_vertex_error']:.3g} | "
                    f"{row[f'lm_{st}_marker_rms']:.3g} | "
                    f"{100 * row[f'lm_{st}_converged']:.0f}% |"
                )
    return (
        "Times are means per frame (ms), one jitted call per frame; BFGS naive is timed on "
        "the replayed frames (same solves as the factored run).\n\n" + "\n".join(lines) + "\n"
    )


def _models(results: dict, starts, run_dir: Path) -> dict:
    """Figs. 9 and 10 over the models: the naive / factored ratio per gradient evaluation
    and per solved frame at each model's largest marker count (``models_speedup.png``),
    BFGS time per frame vs markers per model (``models_time_vs_markers.png``), and the
    models table."""
    from fxspace.plot import plot_model_speedups, plot_vs_markers

    names, ratios, lines = list(results), {}, []
    lines.append(
        "\n| model | joints | depth | vertices | markers | naive/factored per evaluation "
        "(in loop) | " + " | ".join(f"naive/factored per solved frame ({s})" for s in starts) + " |"
    )
    lines.append("|---|---|---|---|---|---|" + "---|" * len(starts))
    ratios["per evaluation"] = []
    for st in starts:
        ratios[f"per solved frame ({st})"] = []
    for name, r in results.items():
        k = max(r["per_markers"], key=int)
        row = r["per_markers"][k]
        ratios["per evaluation"].append(row["ratio_naive_factored_gradient_loop"])
        for st in starts:
            ratios[f"per solved frame ({st})"].append(row[f"ratio_naive_factored_{st}"])
        lines.append(
            f"| {name} | {r['joints']} | {r.get('depth', '')} | {r['vertices']} | {k} | "
            f"{row['ratio_naive_factored_gradient_loop']:.2f}x | "
            + " | ".join(f"{row[f'ratio_naive_factored_{st}']:.2f}x" for st in starts)
            + " |"
        )
    save_figure_atomic(
        plot_model_speedups(names, ratios, title="Fig. 9: factored gradient speed-up per model"),
        run_dir / "models_speedup.png",
    )
    series = {}
    for name, r in results.items():
        ks = sorted(r["per_markers"], key=int)
        for g in ("naive", "factored"):
            series[f"{name} {g}"] = [
                r["per_markers"][k][f"bfgs_{g}_{starts[0]}_ms_mean"] for k in ks
            ]
    counts = sorted({int(k) for r in results.values() for k in r["per_markers"]})
    if all(len(v) == len(counts) for v in series.values()):
        save_figure_atomic(
            plot_vs_markers(
                counts,
                series,
                "mean time per frame [ms]",
                title=f"Fig. 10: BFGS time per frame vs markers ({starts[0]})",
                logy=True,
            ),
            run_dir / "models_time_vs_markers.png",
        )
    return {"ratios": {"models": names, **ratios}, "table": "\n".join(lines) + "\n"}


def _paper_comparison(results: dict, starts) -> dict:
    """Like beside like with the paper's 3.14× (a human model, every frame solved from
    rest): BFGS on eq. (9) over BFGS on eq. (13), time per solved frame, cold, on
    CesiumMan (the shipped human) at its largest marker count. ``None`` when the run
    holds no CesiumMan or no cold start."""
    r = results.get("CesiumMan")
    if r is None or "cold" not in starts:
        return {"model": "CesiumMan", "ratio_per_solved_frame_cold": None}
    k = max(r["per_markers"], key=int)
    row = r["per_markers"][k]
    return {
        "model": "CesiumMan",
        "markers": int(k),
        "ratio_per_solved_frame_cold": row["ratio_naive_factored_cold"],
        "bfgs_factored_cold_ms": row["bfgs_factored_cold_ms_mean"],
        "bfgs_naive_cold_ms": row["bfgs_naive_cold_ms_mean"],
        "what": "BFGS on eq. (9) / BFGS on eq. (13), ms per solved frame, from rest",
    }


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
