"""The navigation experiment's outputs (`fxspace.pipelines.navigation`): the level figures,
the grid, the ρ experiment's figure and the animation (each drawn by `fxspace.plot`, saved
here), ``hierarchy.npz``, ``routes.json`` and the metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace._progress import progress, stage
from fxspace.navigation import is_graph_walk, link_components, link_graph_connected
from fxspace.pipelines._navigation_config import Config, NavSpace
from fxspace.results import result_message
from fxspace.runs import save_figure_atomic, save_npz_atomic, write_json_atomic


def _write_outputs(
    cfg: Config, run_dir: Path, face, h, routes, play, keys, eps_note: str = ""
) -> str | None:
    from fxspace.plot import (
        plot_level,
        plot_levels_grid,
        plot_link_radius_sweep,
        write_navigation_animation,
    )

    nc = cfg.navigation
    stage("figures" + (" and animation" if nc.animation != "none" else ""))
    if nc.level_figures and nc.figure:
        for li in progress(range(len(h.levels)), desc="level figures"):
            rt = next((rr for rr in routes if rr.level == li), None)
            save_figure_atomic(plot_level(h, li, rt), run_dir / f"level_{li:02d}.png")
    title = f"ε = {eps_note}" if eps_note else None
    if nc.figure:
        save_figure_atomic(plot_levels_grid(h, routes, title=title), run_dir / "levels_grid.png")
    if nc.figure and h.link_sweep is not None:
        save_figure_atomic(plot_link_radius_sweep(h.link_sweep, _chosen_scale(h)),
                           run_dir / "link_radius.png")  # fmt: skip
    anim = None
    if nc.figure and nc.animation != "none":
        anim = write_navigation_animation(
            run_dir / f"navigation.{nc.animation}", play, h.embedding, route=routes[0],
            names=face.marker_names, max_frames=nc.animation_frames,
            title=f"key centres {'-'.join(map(str, keys))} (level 0)",
        ).name  # fmt: skip
    final = routes[-1]
    save_npz_atomic(
        run_dir / "hierarchy.npz", embedding=h.embedding, sizes=np.asarray(h.sizes),
        final_frames=final.frames, playback_xy=play.xy, playback_frame=play.frame,
        **{f"centers_{i}": lv.centers for i, lv in enumerate(h.levels)},
        **{f"center_frames_{i}": lv.center_frames for i, lv in enumerate(h.levels)},
    )  # fmt: skip
    write_json_atomic(run_dir / "routes.json", [
        {"level": rt.level, "centres": list(rt.centres), "key_frames": rt.key_frames,
         "frames": rt.frames, "takes": face.take[rt.frames],
         "take_frames": face.frame[rt.frames]}
        for rt in routes
    ])  # fmt: skip
    return anim


def _level_metrics(lv, cold: dict | None = None) -> dict:
    if lv.init in ("kmeans++", "frames"):  # first / finest level: the run itself is cold
        cold = {"num_steps_cold": lv.num_steps, "objective_cold": lv.objective}
    cold = cold or {"num_steps_cold": -1, "objective_cold": float("nan")}
    return {
        "centres": lv.n_clusters,
        "init": lv.init,
        "iterations_warm": lv.num_steps,
        "iterations_split_start": lv.num_steps_split,
        "iterations_all_starts": lv.total_steps,
        "iterations_cold": cold["num_steps_cold"],
        "objective_warm": lv.objective,
        "objective_cold": cold["objective_cold"],
        "converged": lv.converged,
        # the FCM's outcome: "successful" at its fixed point, else why it stopped
        "result": repr(lv.result).removeprefix("RESULTS."),
        "result_message": result_message(lv.result),
        "distinct_centre_frames": int(len(np.unique(lv.center_frames))),
        "links": lv.n_links if lv.links is not None else None,
        "bridges": lv.n_bridges if lv.links is not None else None,
        "link_graph_connected": link_graph_connected(lv) if lv.links is not None else None,
        # groups of centres the links join (the rule alone can leave centres apart)
        "link_pieces": len(np.unique(link_components(lv))) if lv.links is not None else None,
        "radius": lv.radius,
    }


def _chosen_scale(h) -> float | None:
    """The ρ scale the experiment chose: each level's ρ over its centre spacing."""
    from fxspace.navigation import choose_link_scale

    return None if h.link_sweep is None else choose_link_scale(h.link_sweep)


def _rho_experiment(h) -> dict | None:
    """The ρ experiment's table for metrics.json (None when ρ was a fixed number)."""
    sw = h.link_sweep
    if sw is None:
        return None
    return {
        "scales": sw.scales.tolist(),
        "chosen_scale": _chosen_scale(h),
        "levels": [
            {"level": int(li), "centres": int(c), "links": sw.links[k].tolist(),
             "components": sw.components[k].tolist(),
             "coverage": [round(float(v), 6) for v in sw.coverage[k]]}
            for k, (li, c) in enumerate(zip(sw.levels, sw.centres, strict=True))
        ],
    }  # fmt: skip


def _metrics(cfg: Config, face, ns: NavSpace, routes, play, keys, W, anim, timings,
             cold: list | None = None) -> dict:  # fmt: skip
    h = ns.hierarchy
    levels = [_level_metrics(lv, None if cold is None else cold[i])
              for i, lv in enumerate(h.levels)]  # fmt: skip
    # the warm start's own cost: the split start alone, on the levels where it ran
    split = [lv for lv in levels if lv["iterations_split_start"] >= 0]
    warm = sum(lv["iterations_split_start"] for lv in split)
    cold = (sum(lv["iterations_cold"] for lv in split)
            if cfg.hierarchy.compare_cold and ns.kind == "epsilon" else None)  # fmt: skip
    final = routes[-1]
    sweep = None
    if ns.sweep is not None:
        sweep = [
            {"threshold": float(t), "r": float(r) if np.isfinite(r) else None}
            for t, r in zip(ns.sweep.thresholds, ns.sweep.scores, strict=True)
        ]
    return {
        "frames": int(len(ns.embedding)),
        "markers": int(face.positions.shape[1]),
        "takes": list(face.take_names),
        "missing": {
            "policy": cfg.data.missing,
            "max_gap": cfg.data.max_gap,
            **(face.missing or {}),
        },  # fmt: skip
        "reading": face.reading,  # what was read; every drop/resample/conversion said
        "threshold": ns.threshold,
        "threshold_source": ns.threshold_source,
        "criterion": ns.choice["criterion"] if ns.choice else None,
        "sweep": sweep,
        "connecting_threshold": ns.connecting_threshold,
        "r": ns.r,
        "num_levels": len(h.levels),
        "centres_per_level": list(h.sizes),
        "levels": levels,
        # links the paper's ρ rule forbids, added so that every route connects (bridges)
        "links_bridged": sum(lv["bridges"] or 0 for lv in levels),
        "graph_kind": ns.kind,
        # the k-NN graph's pieces (takes) and the edges that joined them (graph.join)
        "graph_joins": ns.joins,
        # every level's FCM at its fixed point ("6/6"), and the reason where a cap stopped one
        "levels_converged": f"{sum(lv['converged'] for lv in levels)}/{len(levels)}",
        "fcm_not_converged": [
            {"level": i, "centres": lv["centres"], "result": lv["result"],
             "message": lv["result_message"], "iterations": lv["iterations_warm"]}
            for i, lv in enumerate(levels) if not lv["converged"]
        ],
        "link_pieces_finest": next(
            (lv["link_pieces"] for lv in reversed(levels) if lv["link_pieces"] is not None), None
        ),
        "rho_experiment": _rho_experiment(h),
        "iterations_split_start_total": warm,
        "iterations_cold_total": cold,
        "iterations_saved_by_warm_start": (cold - warm) if cold is not None else None,
        "iterations_all_starts_total": sum(lv["iterations_all_starts"] for lv in levels),
        "key_centres": keys,
        "route_centres_per_level": [len(rt.centres) for rt in routes],
        "path_length_frames": int(len(final.frames)),
        "path_is_graph_walk": is_graph_walk(final.frames, W),
        "playback_frames": int(len(play.times)),
        "playback_duration_s": float(play.times[-1]),
        "animation": anim,
        "timings": timings,
    }
