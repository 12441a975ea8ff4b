"""The mesh IK experiment's figures and tables (`fxspace.pipelines.mesh_ik`): each figure
drawn by `fxspace.plot` and saved here; ``table.md`` and the paper comparison."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.pipelines._mesh_ik_config import SOLVERS
from fxspace.runs import save_figure_atomic


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
