"""Control-point reconstruction experiment (issues 4, 12 and 21; Hirose & Higuchi).

A real dense face sequence — the AnimFace markers driving a ~6000-vertex face surface by
RBF deformation — of 300 captured frames thinned to 150 as in the paper (the even-numbered
frames dropped, ``thin = 2``) is cut into segments by the fused lasso, the **number of
segments chosen from the data** (``n_segments = 0``: the elbow of the refitted error along
the fused-lasso λ path, or BIC; a positive count overrides), and **every** segment is
modelled by 20–30 control points (kernel k-means, 20 restarts); the stitched scene shares
each boundary frame between its two segments. A sweep over (clusters, kernel width γ) on
the most complex segment picks the parameters by BIC. That segment is also refined by
gradient fitting (optax); a key on the face moves the region under the left mouth corner
(a smirk), saved as ``edits.json`` for the editor (``fxspace studio RUN_DIR``).

Reports eq. (1) of linear interpolation vs ours for the whole scene
(``error_ratio_scene``), per segment (``error_ratio_segments``) and, next to the paper's
16.44 → 1.82 on its 43-frame segment, for our segment closest to 43 frames
(``error_ratio_paper_segment``, its frames in ``paper_segment``). A character — the
project's stand-in (the capture's face with other proportions) or a user's OBJ/.glb with
a marker map and optional first/last frames — is driven by the capture through the
control points and exported as an animated glTF (``character.glb``), read back to check.
The dense sequence is either that RBF surface (``dense_source = "rbf"``) or the real
head's face-area vertices (``"head"``: the rig at ``head``, the ICT Face Model's 9 409,
solved from the markers, `fxspace.face`); where the rig is present the other source runs
the same scene pipeline too, and the metrics name the error ratio of each
(``error_ratio_by_dense_source``, ``error_ratio_scene_rbf``, ``error_ratio_scene_head``).
Stages (`STAGES`) are cached in the run folder, so an interrupted run resumes.
``file = "synthetic"`` runs on the project's synthetic face (no data needed).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress
from fxspace._progress import stage as stage_line
from fxspace.controlpoints import (
    compression_ratio,
    face_surface,
    fit_control_points,
    fit_scene,
    rbf_deform,
    reconstruct,
    reconstruction_error,
    refine_control_points,
    scene_errors,
    scene_from_arrays,
    scene_to_arrays,
    segments_from_boundaries,
    storage_size,
)
from fxspace.pipelines._reconstruction_config import FACE_RADIUS_MM as FACE_RADIUS_MM
from fxspace.pipelines._reconstruction_config import PAPER as PAPER
from fxspace.pipelines._reconstruction_config import SYNTHETIC as SYNTHETIC
from fxspace.pipelines._reconstruction_config import Config as Config
from fxspace.pipelines._reconstruction_config import _edit_marker as _edit_marker
from fxspace.pipelines._reconstruction_config import _head_path as _head_path
from fxspace.pipelines._reconstruction_config import _neutral as _neutral
from fxspace.pipelines._reconstruction_config import _path as _path
from fxspace.pipelines._reconstruction_config import _read_capture as _read_capture
from fxspace.pipelines._reconstruction_config import data_files as data_files
from fxspace.pipelines._reconstruction_metrics import _by_source as _by_source
from fxspace.pipelines._reconstruction_metrics import _metrics as _metrics
from fxspace.pipelines._reconstruction_metrics import paper_segment as paper_segment
from fxspace.pipelines._reconstruction_outputs import _edit_keys as _edit_keys
from fxspace.pipelines._reconstruction_outputs import _editor_files as _editor_files
from fxspace.pipelines._reconstruction_outputs import _figures as _figures
from fxspace.pipelines._reconstruction_outputs import _head_outputs as _head_outputs
from fxspace.pipelines._reconstruction_outputs import _write_outputs as _write_outputs
from fxspace.pipelines._reconstruction_stages import _bic as _bic
from fxspace.pipelines._reconstruction_stages import _character as _character
from fxspace.pipelines._reconstruction_stages import _gltf_source as _gltf_source
from fxspace.pipelines._reconstruction_stages import _lin_error as _lin_error
from fxspace.pipelines._reconstruction_stages import _marker_map as _marker_map
from fxspace.pipelines._reconstruction_stages import _read_mesh as _read_mesh
from fxspace.pipelines._reconstruction_stages import _scene as _scene
from fxspace.pipelines._reconstruction_stages import _segmentation as _segmentation
from fxspace.runs import cached, cached_arrays

__all__ = ["Config", "run", "prepare_app", "PAPER", "STAGES", "data_files"]

STAGES: tuple[str, ...] = (
    "dense", "segmentation", "sweep", "scene", "refine", "character", "gltf_source",
    "other_source", "app_scene",
)  # fmt: skip
APP = "fxspace.studio._editor:serve"  # `fxspace studio` of a run: the control-point editor
REPRODUCTION = "hirose-higuchi"  # its reproduction page (`fxspace docs`)


def _dense(cfg: Config, M: np.ndarray) -> dict:
    """Stage ``dense``: markers → face surface by RBF deformation (timed, compile excluded)."""
    times = []
    for _ in range(2):  # the first call compiles
        t = time.perf_counter()
        surf = face_surface(M[0], cfg.n_vertices)
        X = rbf_deform(surf.vertices, M[0], M)
        X.block_until_ready()
        times.append(time.perf_counter() - t)
    return {"X": np.asarray(X), "faces": surf.faces, "marker_vertex": surf.marker_vertex,
            "times": np.asarray(times)}  # fmt: skip


def _dense_head(cfg: Config, M: np.ndarray, names) -> dict:
    """Stage ``dense`` with ``dense_source = "head"``: the rig (``head``) bound to the
    neutral markers and solved from every frame (`fxspace.face`), its face-area vertices
    (ICT: 9 409) posed where the capture is, in the capture's units (timed, compile
    excluded); each marker's vertex is its bound triangle's nearest corner."""
    from fxspace.face import bind_markers, posed_vertices, read_rig, solve_weights

    rig = read_rig(_head_path(cfg))
    vs = np.asarray(rig.vertex_sets.get("face", np.arange(rig.num_vertices)))
    local = np.full(rig.num_vertices, -1, np.int64)
    local[vs] = np.arange(len(vs))
    faces = local[np.asarray(rig.faces)[rig.face_triangles("face")]].astype(np.int32)
    neutral = _neutral(cfg, M)
    times = []
    for _ in range(2):  # the first call compiles
        t = time.perf_counter()
        b = bind_markers(rig, neutral, list(names), units="mm")
        sol = solve_weights(rig, b, M, names=list(names), units="mm")
        X = posed_vertices(rig, b, sol, vertices=vs)
        X.block_until_ready()
        times.append(time.perf_counter() - t)
    for line in sol.notes:
        print(f"[reconstruction] the head (dense source): {line}", flush=True)
    mv = local[b.corners[np.arange(len(names)), np.argmax(b.barycentric, axis=1)]]
    return {"X": np.asarray(X, np.float64), "faces": faces, "marker_vertex": mv.astype(np.int64),
            "times": np.asarray(times)}  # fmt: skip


def _dense_of(cfg: Config, M: np.ndarray, names, source: str) -> dict:
    return _dense_head(cfg, M, names) if source == "head" else _dense(cfg, M)


def _other_source(cfg: Config, M: np.ndarray, names, c: int, g: float, key) -> dict:
    """Stage ``other_source``: the same scene pipeline (segments chosen from the data, the
    chosen control points and γ) on the other dense source, for its error ratio."""
    other = "rbf" if cfg.dense_source == "head" else "head"
    d = _dense_of(cfg, M, names, other)
    X = jnp.asarray(d["X"])
    fit = fit_scene(
        X, c, n_segments="auto" if cfg.n_segments == 0 else cfg.n_segments,
        min_length=cfg.min_length, segment_on=cfg.segment_on, gamma=g, key=key,
        n_init=cfg.n_init, max_points=cfg.max_points, refine_steps=cfg.refine_steps,
        method=cfg.cluster_method, segment_criterion=cfg.segment_criterion,
    )  # fmt: skip
    e = scene_errors(X, fit.model)
    pi = paper_segment(fit.model.boundaries, e, cfg.paper_segment_frames)
    return {
        "source": other,
        "n_vertices": int(X.shape[1]),
        "n_segments": len(fit.model.boundaries) - 1,
        "error_ratio_scene": float(e.ratio_scene),
        "error_ratio_paper_segment": float(e.ratio[pi]),
        "linear_error_scene": float(e.linear_scene),
        "ours_error_scene": float(e.model_scene),
    }


def _sweep(S, cfg: Config, key) -> list[dict]:
    rows = []
    n = int(np.prod(S.shape))
    lin = _lin_error(S)
    grid = [(c, g) for c in cfg.clusters for g in cfg.gammas]
    for c, g in progress(grid, desc="(clusters, γ) sweep"):
        model, km = fit_control_points(
            S, min(c, S.shape[1]), gamma=g, key=key, n_init=cfg.n_init,
            max_points=cfg.max_points, refine_steps=cfg.refine_steps, method=cfg.cluster_method,
        )  # fmt: skip
        err = float(reconstruction_error(S, reconstruct(model)))
        rows.append({
            "clusters": c, "gamma": g, "error": err, "ratio": err / lin,
            "compression": compression_ratio(model), "bic": _bic(err, n, storage_size(model)),
            "kkm_steps": int(km.num_steps), "kkm_converged": bool(km.converged),
        })  # fmt: skip
    return rows


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the experiment in ``run_dir`` (every costly stage cached there); returns the
    metrics."""
    cfg.validate()
    with jax.enable_x64(cfg.x64):
        return _run(cfg, Path(run_dir), seed)


def prepare_app(cfg: Config, run_dir: Path, seed: int) -> None:
    """What the editor shows, and only that (``fxspace studio CONFIG``): the dense
    sequence, its segments and one scene model, written as ``scene.npz`` with the
    demonstration edit. The control points and γ are the sweep's choice when the run
    folder holds the sweep, else the middle of the config's grid (``fxspace run``
    sweeps and picks them by BIC). The stages are the run's own (a later ``fxspace
    run`` reuses them), the scene a stage of its own (``app_scene``)."""
    cfg.validate()
    run_dir = Path(run_dir)
    with jax.enable_x64(cfg.x64):
        key = jax.random.PRNGKey(seed)
        M, names, rate, _ = _read_capture(cfg, seed)
        dense = cached_arrays(
            run_dir, "dense", _say("dense", lambda: _dense_of(cfg, M, names, cfg.dense_source))
        )
        X = jnp.asarray(dense["X"])
        sg = cached_arrays(
            run_dir, "segmentation", _say("segmentation", lambda: _segmentation(cfg, X))
        )
        n_seg = len(sg["boundaries"]) - 1
        sweep = run_dir / "cache" / "sweep.json"
        if sweep.is_file():
            best = min(json.loads(sweep.read_text()), key=lambda r: r["bic"])
            c, g, why = int(best["clusters"]), float(best["gamma"]), "the sweep's choice (BIC)"
        else:
            c, g = cfg.clusters[len(cfg.clusters) // 2], cfg.gammas[len(cfg.gammas) // 2]
            why = "the grid's middle; fxspace run picks them by BIC"
        stage_line(f"the editor's scene: {c} control points, γ = {g} ({why})")

        def one() -> dict:
            fit = fit_scene(
                X, c, n_segments=n_seg, min_length=cfg.min_length, segment_on=cfg.segment_on,
                gamma=g, key=key, n_init=cfg.n_init, max_points=cfg.max_points,
                refine_steps=cfg.refine_steps, method=cfg.cluster_method,
            )  # fmt: skip
            return scene_to_arrays(fit.model)

        scene = scene_from_arrays(cached_arrays(run_dir, "app_scene", _say("app_scene", one)))
        si = int(np.argmax(scene_errors(X, scene).linear))
        keys = _edit_keys(cfg, scene, names, dense["marker_vertex"], si)
        _editor_files(run_dir, X, M, names, rate, dense, scene, g, keys)


def _say(stage: str, fn):
    """``fn`` announced as it starts (only runs when the stage is not cached)."""

    def go():
        i = STAGES.index(stage) + 1
        stage_line(f"reconstruction stage {i}/{len(STAGES)}: {stage} …")
        return fn()

    return go


def _run(cfg: Config, run_dir: Path, seed: int) -> dict:
    key = jax.random.PRNGKey(seed)
    M, names, rate, units = _read_capture(cfg, seed)
    dense = cached_arrays(
        run_dir, "dense", _say("dense", lambda: _dense_of(cfg, M, names, cfg.dense_source))
    )
    X = jnp.asarray(dense["X"])
    sg = cached_arrays(run_dir, "segmentation", _say("segmentation", lambda: _segmentation(cfg, X)))
    bounds0 = sg["boundaries"]
    errs0 = [_lin_error(X[a : b + 1]) for a, b in segments_from_boundaries(bounds0)]
    a0, b0 = segments_from_boundaries(bounds0)[int(np.argmax(errs0))]
    rows = cached(run_dir, "sweep", _say("sweep", lambda: _sweep(X[a0 : b0 + 1], cfg, key)))
    best = min(rows, key=lambda r: r["bic"])
    c, g = int(best["clusters"]), float(best["gamma"])
    n_seg = len(bounds0) - 1
    sc = cached_arrays(run_dir, "scene", _say("scene", lambda: _scene(cfg, X, n_seg, c, g, key)))
    scene = scene_from_arrays(sc)
    errs = scene_errors(X, scene)
    si = int(np.argmax(errs.linear))  # the most complex segment
    a, b = segments_from_boundaries(scene.boundaries)[si]
    S, model = X[a : b + 1], scene.segments[si]

    def refine() -> dict:
        t = time.perf_counter()
        fr = refine_control_points(S, model, steps=max(cfg.fit_steps, 1),
                                   support=min(cfg.fit_support, model.controls.shape[0]),
                                   smoothness=cfg.fit_smoothness)  # fmt: skip
        fr.error.block_until_ready()
        return {"controls": fr.model.controls, "weights": fr.model.weights,
                "error": fr.error, "converged": fr.converged,
                "time_s": np.float64(time.perf_counter() - t)}  # fmt: skip

    rf = cached_arrays(run_dir, "refine", _say("refine", refine))
    fitted = model._replace(
        controls=jnp.asarray(rf["controls"]), weights=jnp.asarray(rf["weights"])
    )
    ch = None
    keys = _edit_keys(cfg, scene, names, dense["marker_vertex"], si)
    if cfg.character:
        X0 = np.asarray(X[0])
        ch = cached_arrays(
            run_dir,
            "character",
            _say("character", lambda: _character(cfg, M, names, scene, X0, keys)),
        )
    gl = (
        cached(run_dir, "gltf_source", _say("gltf_source", lambda: _gltf_source(cfg, key)))
        if cfg.gltf_mesh
        else {}
    )
    both = cfg.head and cfg.file != SYNTHETIC and _head_path(cfg).exists()
    oth = (cached(run_dir, "other_source",
                  _say("other_source", lambda: _other_source(cfg, M, names, c, g, key)))
           if both else {})  # fmt: skip
    ctx = dict(cfg=cfg, run_dir=run_dir, M=M, names=names, rate=rate, units=units, oth=oth,
               dense=dense, sg=sg, X=X, scene=scene, errs=errs, si=si, fitted=fitted,
               rf=rf, rows=rows, c=c, g=g, sc=sc, ch=ch, gl=gl, keys=keys)  # fmt: skip
    outputs = _write_outputs(ctx)
    return _metrics(ctx, outputs)
