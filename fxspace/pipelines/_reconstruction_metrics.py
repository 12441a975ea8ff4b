"""The reconstruction experiment's metrics (`fxspace.pipelines.reconstruction`): eq. (1)
of linear interpolation vs ours for the scene, per segment and for the segment closest to
the paper's 43 frames, per dense source."""

from __future__ import annotations

import json

import numpy as np

from fxspace.controlpoints import (
    ControlPointModel,
    compression_ratio,
    scene_compression_ratio,
    segments_from_boundaries,
)
from fxspace.pipelines._reconstruction_config import PAPER, Config, _edit_marker


def paper_segment(boundaries, errors, frames: int = 43) -> int:
    """Index of the segment closest in length to the paper's (``frames`` frames after
    thinning); ties go to the larger linear-interpolation error."""
    spans = segments_from_boundaries(boundaries)
    lens = np.array([e - a + 1 for a, e in spans])
    gap = np.abs(lens - frames)
    cand = np.flatnonzero(gap == gap.min())
    return int(cand[int(np.argmax(np.asarray(errors.linear)[cand]))])


def _by_source(cfg: Config, errs, pi: int, X, oth: dict) -> dict:
    """The paper's error ratio for each dense source, named: the run's own and, where the
    rig is there, the other (``other_source``)."""
    own = {"source": cfg.dense_source, "n_vertices": int(X.shape[1]),
           "n_segments": len(errs.ratio), "error_ratio_scene": float(errs.ratio_scene),
           "error_ratio_paper_segment": float(errs.ratio[pi]),
           "linear_error_scene": float(errs.linear_scene),
           "ours_error_scene": float(errs.model_scene)}  # fmt: skip
    return {d["source"]: d for d in (own, oth) if d}


def _metrics(ctx: dict, out: dict) -> dict:
    cfg, scene, errs, si, X = ctx["cfg"], ctx["scene"], ctx["errs"], ctx["si"], ctx["X"]
    bounds = scene.boundaries
    a, b = segments_from_boundaries(bounds)[si]
    model: ControlPointModel = scene.segments[si]
    lin, err = float(errs.linear[si]), float(errs.model[si])
    n_vals = (b - a + 1) * X.shape[1]
    pi = paper_segment(bounds, errs, cfg.paper_segment_frames)
    pa, pb = segments_from_boundaries(bounds)[pi]
    sel = json.loads(str(ctx["sg"]["selection"]))
    pipe_s = float(np.median(ctx["sc"]["times"]))
    dense_t = ctx["dense"]["times"]
    fit_err = float(ctx["rf"]["error"])
    by_source = _by_source(cfg, errs, pi, X, ctx["oth"])
    metrics = {
        "data": {"file": cfg.file, "start": cfg.start, "n_frames_captured": cfg.n_frames,
                 "thin": cfg.thin, "n_frames": int(X.shape[0]),
                 "n_vertices": int(X.shape[1]), "n_markers": int(ctx["M"].shape[1])},
        "segmentation": {"boundaries": bounds.tolist(), "lambda": float(ctx["sg"]["lam"]),
                         "n_segments": len(bounds) - 1, "selection": sel,
                         "linear_error_per_segment": errs.linear.tolist()},
        "n_segments_chosen": len(bounds) - 1,
        "n_segments_why": sel.get("why", ""),
        "error_ratio_scene": errs.ratio_scene,
        "dense_source": cfg.dense_source,
        "error_ratio_by_dense_source": by_source,
        **{f"error_ratio_scene_{k}": v["error_ratio_scene"] for k, v in by_source.items()},
        "error_ratio_segments": errs.ratio.tolist(),
        "error_ratio_paper_segment": float(errs.ratio[pi]),
        "paper_segment": {"index": pi, "frames": [pa, pb], "n_frames": pb - pa + 1,
                          "linear_error": float(errs.linear[pi]),
                          "ours_error": float(errs.model[pi]),
                          "paper": {"n_frames": 43, "linear_error": 16.44, "ours_error": 1.82,
                                    "ratio": 1.82 / 16.44}},
        "linear_error_scene": errs.linear_scene, "ours_error_scene": errs.model_scene,
        "ours_error_per_segment": errs.model.tolist(),
        "scene_compression_ratio": scene_compression_ratio(scene),
        "scene_pipeline_time_s": pipe_s,
        "scene_pipeline_first_call_s": float(ctx["sc"]["first_s"]),
        "segment": [a, b], "segment_index": si, "segment_frames": b - a + 1,
        "chosen": {"clusters": ctx["c"], "gamma": ctx["g"],
                   "criterion": "BIC (most complex segment)"},
        "sweep": ctx["rows"],
        "linear_error": lin, "ours_error": err, "ratio": err / lin,
        "compression_ratio": compression_ratio(model),
        "fitted_error": fit_err, "fitted_ratio": fit_err / lin,
        "fitted_compression_ratio": compression_ratio(ctx["fitted"]),
        "fit_converged": bool(ctx["rf"]["converged"]),
        "linear_rmse_mm": float(np.sqrt(lin / n_vals)),
        "ours_rmse_mm": float(np.sqrt(err / n_vals)),
        "fitted_rmse_mm": float(np.sqrt(fit_err / n_vals)),
        "kkm_restarts": cfg.n_init, "kkm_steps": int(ctx["sc"]["kkm_steps"][si]),
        "pipeline_time_s": pipe_s, "pipeline_first_call_s": float(ctx["sc"]["first_s"]),
        "dense_transfer_time_s": float(dense_t[-1]),
        "dense_transfer_first_call_s": float(dense_t[0]),
        "pipeline_with_dense_transfer_s": pipe_s + float(dense_t[-1]),
        "fit_time_s": float(ctx["rf"]["time_s"]),
        "units": "mm", "file_units": ctx["units"],
        "edit": {"anchor_vertex": out["vi"],
                 "marker": ctx["names"][_edit_marker(cfg, ctx["names"])],
                 "keys": [k._asdict() for k in out["keys"]], "vertices_moved": out["moved"]},
        "targets": {"ratio_scene_le_0.11": errs.ratio_scene <= 0.11,
                    "ratio_segments_le_0.11": bool(np.all(errs.ratio <= 0.11)),
                    "scene_pipeline_le_18s": pipe_s <= 18.0},
        "character": out.get("character", {}),
        "head": out.get("head", {}),
        "paper": PAPER,
        "gltf": ctx["gl"],
    }  # fmt: skip
    print(
        f"[reconstruction] scene {X.shape[0]} frames × {X.shape[1]} vertices, "
        f"{len(bounds) - 1} segments ({sel.get('why', '')}): ratio {errs.ratio_scene:.4f}; "
        f"paper-like segment {pa}–{pb} ({pb - pa + 1} frames): {float(errs.linear[pi]):.4g} → "
        f"{float(errs.model[pi]):.4g} (×{float(errs.ratio[pi]):.3f}; paper 16.44 → 1.82, "
        f"×0.111); whole-scene pipeline {pipe_s:.2f} s"
    )
    return metrics
