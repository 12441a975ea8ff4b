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

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress
from fxspace._progress import stage as stage_line
from fxspace.config import ConfigError
from fxspace.controlpoints import (
    ControlPointModel,
    FaceKey,
    Segmentation,
    character,
    compression_ratio,
    drive_character,
    edited_vertices,
    face_surface,
    fit_control_points,
    fit_scene,
    linear_interpolation,
    rbf_deform,
    reconstruct,
    reconstruct_scene,
    reconstruction_error,
    refine_control_points,
    save_edits,
    scene_compression_ratio,
    scene_errors,
    scene_from_arrays,
    scene_to_arrays,
    segment_motion,
    segments_from_boundaries,
    standin_character,
    storage_size,
    thin_frames,
)
from fxspace.data import data_path
from fxspace.errors import DataNotFoundError
from fxspace.results import RESULTS
from fxspace.runs import cached, cached_arrays, save_figure_atomic, save_npz_atomic

__all__ = ["Config", "run", "prepare_app", "PAPER", "STAGES", "data_files"]

PAPER = {"linear_error": 16.44, "ours_error": 1.82, "ratio": 0.11, "time_s": 18.0,
         "segments": 8, "segment_frames": 43}  # fmt: skip
STAGES: tuple[str, ...] = (
    "dense", "segmentation", "sweep", "scene", "refine", "character", "gltf_source",
    "other_source", "app_scene",
)  # fmt: skip
APP = "fxspace.studio._editor:serve"  # `fxspace studio` of a run: the control-point editor
SYNTHETIC = "synthetic"


@dataclasses.dataclass(frozen=True)
class Config:
    """See ``configs/reconstruction.toml`` for the meaning of every field."""

    file: str = "face/animface_cheeks.c3d"
    start: int = 300
    n_frames: int = 300
    thin: int = 2
    n_vertices: int = 6000
    n_segments: int = 0
    segment_criterion: str = "elbow"
    segment_on: str = "velocity"
    min_length: int = 4
    clusters: tuple[int, ...] = (20, 25, 30)
    gammas: tuple[float, ...] = (0.25, 0.5, 1.0)
    n_init: int = 20
    max_points: int = 1000
    refine_steps: int = 10
    cluster_method: str = "kernel"
    fit_steps: int = 300
    fit_support: int = 3
    fit_smoothness: float = 1e-4
    edit_offset_mm: tuple[float, ...] = (6.0, 8.0, 0.0)
    edit_marker: str = "Mouth_Lend"
    timing_repeats: int = 2
    paper_segment_frames: int = 43
    character: str = "standin"
    character_markers: str = ""
    character_first: str = ""
    character_last: str = ""
    character_vertices: int = 3000
    head: str = "face/ict"
    dense_source: str = "rbf"
    gltf_mesh: str = "CesiumMan"
    gltf_frames: int = 150
    gltf_clusters: int = 25
    x64: bool = True

    def validate(self) -> None:
        """Every config check, naming the key (`fxspace.config.ConfigError`)."""
        for k in ("start", "n_segments", "refine_steps", "fit_steps"):
            if getattr(self, k) < 0:
                raise ConfigError(f"{k} must be >= 0, got {getattr(self, k)}")
        for k in ("n_frames", "thin", "n_vertices", "min_length", "n_init", "max_points",
                  "fit_support", "timing_repeats", "paper_segment_frames", "gltf_frames",
                  "gltf_clusters", "character_vertices"):  # fmt: skip
            if getattr(self, k) < 1:
                raise ConfigError(f"{k} must be >= 1, got {getattr(self, k)}")
        if self.n_frames // self.thin < 3 * max(self.n_segments, 1):
            raise ConfigError(
                f"n_frames/thin = {self.n_frames // self.thin} too short for n_segments="
                f"{self.n_segments}"
            )
        if self.cluster_method not in ("kernel", "hybrid"):
            raise ConfigError(
                f"cluster_method must be 'kernel' (kernel k-means to the end, the paper's) or "
                f"'hybrid' (kernel k-means on a subset, Euclidean steps for the rest), got "
                f"{self.cluster_method!r}"
            )
        if self.segment_criterion not in ("elbow", "bic"):
            raise ConfigError(
                f"segment_criterion must be 'elbow' or 'bic', got {self.segment_criterion!r}"
            )
        if self.dense_source not in ("rbf", "head"):
            raise ConfigError(
                f"dense_source must be 'rbf' (the markers drive a face surface by RBF) or "
                f"'head' (the solved rig's face-area vertices), got {self.dense_source!r}"
            )
        if self.dense_source == "head" and (not self.head or self.file == SYNTHETIC):
            raise ConfigError(
                "dense_source = 'head' needs a rig (head = \"face/ict\") and a named capture "
                '(not file = "synthetic")'
            )
        if self.segment_on not in ("velocity", "position"):
            raise ConfigError(
                f"segment_on must be 'velocity' or 'position', got {self.segment_on!r}"
            )
        if not self.clusters or min(self.clusters) < 1 or not self.gammas or min(self.gammas) <= 0:
            raise ConfigError("clusters must be integers >= 1 and gammas numbers > 0 (non-empty)")
        if len(self.edit_offset_mm) != 3 or not np.all(np.isfinite(self.edit_offset_mm)):
            raise ConfigError(f"edit_offset_mm must be 3 finite numbers, got {self.edit_offset_mm}")
        if self.fit_smoothness < 0 or not np.isfinite(self.fit_smoothness):
            raise ConfigError(f"fit_smoothness must be finite and >= 0, got {self.fit_smoothness}")
        if self.character not in ("", "standin") and not self.character_markers:
            raise ConfigError(
                "character_markers must name a JSON {marker name: vertex index} file when "
                "character is a mesh file"
            )


def _path(name: str) -> Path:
    return data_path(name)


def _head_path(cfg: Config) -> Path:
    """The rig folder ``head``; when it is absent the error says how to run without it."""
    try:
        return data_path(cfg.head)
    except DataNotFoundError as e:
        raise DataNotFoundError(
            f"head: {e}; set head = \"\" in the config to run without the head (no "
            "head.glb, no head metrics), or point head at a rig folder"
        ) from None


def data_files(cfg: Config) -> list[Path]:
    """The files a run reads (for its content key)."""
    files = [] if cfg.file == SYNTHETIC else [_path(cfg.file)]
    if cfg.head and cfg.file != SYNTHETIC and _head_path(cfg).is_dir():
        files += sorted(p for p in _head_path(cfg).iterdir() if p.is_file())
    for f in (cfg.character if cfg.character not in ("", "standin") else "",
              cfg.character_markers, cfg.character_first, cfg.character_last):  # fmt: skip
        if f:
            files.append(_path(f))
    return files


#: the RMS radius of a face's markers about their centroid, in mm, that a capture must
#: have (AnimFace: 66 mm; the synthetic face: 56 mm); outside it the units are wrong
FACE_RADIUS_MM = (20.0, 400.0)


def _read_capture(cfg: Config, seed: int) -> tuple[np.ndarray, tuple[str, ...], float, str]:
    """``(markers (T, M, 3) thinned, names, rate, units)`` of the configured capture, in
    millimetres (every ``*_mm`` metric and the edit's ``edit_offset_mm`` are in mm): a
    capture in other length units is converted (its unit kept as ``file_units``), one
    whose unit is not a length, or whose face is not of a face's size in mm (metre
    values labelled mm), is refused with the fix."""
    from fxspace.io import UNIT_SCALES, read_markers
    from fxspace.synthetic import synthetic_face

    if cfg.file == SYNTHETIC:
        sf = synthetic_face(41, cfg.start + cfg.n_frames, seed=seed, rate=60.0)
        seq = sf.sequence
    else:
        seq = read_markers(_path(cfg.file))
    if seq.units not in UNIT_SCALES:
        raise ConfigError(
            f"file {cfg.file}: its units {seq.units!r} are not a length unit "
            f"{sorted(UNIT_SCALES)}; fix the file's unit label"
        )
    file_units = seq.file_units or seq.units
    seq = seq.to_units("mm") if seq.units != "mm" else seq
    P = np.asarray(seq.positions, dtype=np.float64)
    if cfg.start + cfg.n_frames > P.shape[0]:
        raise ConfigError(
            f"start + n_frames = {cfg.start + cfg.n_frames} exceeds the {P.shape[0]} frames "
            f"of {cfg.file}"
        )
    M = np.asarray(thin_frames(P[cfg.start : cfg.start + cfg.n_frames], cfg.thin))
    if np.isnan(M).any():
        raise ConfigError(
            f"{cfg.file} frames {cfg.start}… have missing markers; pick another start"
        )
    radius = float(np.sqrt(np.mean(np.sum((M[0] - M[0].mean(0)) ** 2, axis=1))))
    lo, hi = FACE_RADIUS_MM
    if not lo <= radius <= hi:
        raise ConfigError(
            f"file {cfg.file}: the face's markers spread {radius:.3g} mm about their centre "
            f"(a face: {lo:g}–{hi:g} mm) with its units read as {file_units!r}: the values "
            "are in another unit than the file says (metres labelled mm?); fix the file's "
            "unit label"
        )
    _edit_marker(cfg, seq.names)  # a misspelt edit_marker stops the run before any stage
    return M, tuple(seq.names), seq.rate / cfg.thin, file_units


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


def _segmentation(cfg: Config, X) -> dict:
    """Stage ``segmentation``: the fused-lasso cut, the count chosen from the data."""
    n = "auto" if cfg.n_segments == 0 else cfg.n_segments
    seg = segment_motion(X, n, min_length=cfg.min_length, on=cfg.segment_on,  # type: ignore[arg-type]
                         criterion=cfg.segment_criterion)  # type: ignore[arg-type]  # fmt: skip
    sel = seg.selection or {"criterion": "given", "chosen": cfg.n_segments,
                            "why": "n_segments set in the config"}  # fmt: skip
    return {"boundaries": seg.boundaries, "summary": seg.summary, "fit": seg.fit,
            "lam": np.float64(seg.lam), "jump_energy": seg.jump_energy,
            "selection": np.asarray(json.dumps(sel))}  # fmt: skip


def _bic(err: float, n: int, k: int) -> float:
    return n * float(np.log(max(err, 1e-300) / n)) + k * float(np.log(n))


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


def _scene(cfg: Config, X, n_segments: int, c: int, g: float, key) -> dict:
    """Stage ``scene``: the whole-scene pipeline (segments → every segment's control
    points → stitched reconstruction), compiled once then timed."""

    def once(show: bool):
        fit = fit_scene(
            X, c, n_segments=n_segments, min_length=cfg.min_length, segment_on=cfg.segment_on,
            gamma=g, key=key, n_init=cfg.n_init, max_points=cfg.max_points,
            refine_steps=cfg.refine_steps, method=cfg.cluster_method, show_progress=show,
        )  # fmt: skip
        reconstruct_scene(fit.model).block_until_ready()
        return fit

    t = time.perf_counter()
    once(True)
    first = time.perf_counter() - t
    times = []
    for _ in range(max(1, cfg.timing_repeats)):
        t = time.perf_counter()
        fit = once(False)
        times.append(time.perf_counter() - t)
    kkm = [int(k.num_steps) for k in fit.clusterings]
    return {**scene_to_arrays(fit.model), "first_s": np.float64(first),
            "times": np.asarray(times), "kkm_steps": np.asarray(kkm)}  # fmt: skip


def _marker_map(path: Path, names: tuple[str, ...], n_vertices: int) -> np.ndarray:
    try:
        raw = json.loads(path.read_text())
        mv = np.asarray([int(raw[n]) for n in names], np.int64)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(
            f"character_markers {path}: need a JSON object mapping every capture marker "
            f"name to a vertex index ({e!r})"
        ) from None
    if mv.min() < 0 or mv.max() >= n_vertices:
        raise ConfigError(f"character_markers {path}: vertex indices must be in [0, {n_vertices})")
    return mv


def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    from fxspace.io import read_gltf_morph, read_obj

    if path.suffix.lower() == ".obj":
        return read_obj(path)
    if path.suffix.lower() == ".glb":
        m = read_gltf_morph(path)
        return m.vertices[0], m.faces
    raise ConfigError(f"character mesh {path}: use an .obj or .glb file")


def _character(cfg: Config, M: np.ndarray, names, scene, X0, keys) -> dict:
    """Stage ``character``: the target face driven by the capture through the control
    points, carrying the animator's edits ``keys`` (`fxspace.drive_character`)."""
    if cfg.character == "standin":
        ch = standin_character(M[0], cfg.character_vertices)
    else:
        V, F = _read_mesh(_path(cfg.character))
        mv = _marker_map(_path(cfg.character_markers), names, len(V))
        first = _read_mesh(_path(cfg.character_first))[0] if cfg.character_first else None
        last = _read_mesh(_path(cfg.character_last))[0] if cfg.character_last else None
        ch = character(V, F, mv, first, last)
    Y = drive_character(ch, scene, M, X0, edits=keys)
    Y0 = drive_character(ch, scene, M, X0)  # unedited, to report what the edit moved
    moved = np.linalg.norm(Y - Y0, axis=2).max(0)
    return {"vertices": Y, "faces": ch.faces, "rest": ch.vertices, "edit_moved": moved}


def _gltf_source(cfg: Config, key) -> dict:
    """The same pipeline on the vertex sequence of a skinned glTF animation."""
    from fxspace.io import read_gltf
    from fxspace.mesh import animation_vertices

    mesh = read_gltf(data_path("mesh", f"{cfg.gltf_mesh}.glb"))
    t0, t1 = mesh.animation_range(0)
    X = jnp.asarray(animation_vertices(mesh, 0, np.linspace(t0, t1, cfg.gltf_frames)))
    t = time.perf_counter()
    n = "auto" if cfg.n_segments == 0 else cfg.n_segments
    seg = segment_motion(X, n, min_length=cfg.min_length, on=cfg.segment_on,  # type: ignore[arg-type]
                         criterion=cfg.segment_criterion)  # type: ignore[arg-type]  # fmt: skip
    errs = [_lin_error(X[a : b + 1]) for a, b in segments_from_boundaries(seg.boundaries)]
    a, b = segments_from_boundaries(seg.boundaries)[int(np.argmax(errs))]
    S = X[a : b + 1]
    model, _ = fit_control_points(
        S,
        min(cfg.gltf_clusters, S.shape[1]),
        key=key,
        n_init=cfg.n_init,
        max_points=cfg.max_points,
        method=cfg.cluster_method,  # type: ignore[arg-type]
    )
    err = float(reconstruction_error(S, reconstruct(model)))
    return {
        "mesh": cfg.gltf_mesh, "animation": mesh.animation_names[0],
        "n_vertices": int(X.shape[1]), "n_frames": int(X.shape[0]),
        "boundaries": seg.boundaries.tolist(), "segment": [a, b],
        "linear_error": max(errs), "ours_error": err, "ratio": err / max(errs),
        "compression": compression_ratio(model),
        "time_s_with_compile": time.perf_counter() - t,
    }  # fmt: skip


def _lin_error(S) -> float:
    """Eq. (1) of linear interpolation over segment ``S`` (on the host: no program per
    segment length)."""
    S = np.asarray(S)
    s = np.linspace(0.0, 1.0, S.shape[0]).reshape((-1,) + (1,) * (S.ndim - 1))
    return float(np.sum((S - ((1.0 - s) * S[0] + s * S[-1])) ** 2))


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


def _editor_files(run_dir: Path, X, M, names, rate: float, dense: dict, scene, g: float,
                  keys) -> None:  # fmt: skip
    """``scene.npz`` (what the editor opens) and, unless the animator's are there,
    ``edits.json`` with the demonstration keys."""
    from fxspace.runs import unrecorded

    if not (run_dir / "edits.json").exists():  # the animator's saved keys are theirs:
        with unrecorded():  # never in the manifest, never overwritten by a rerun
            save_edits(
                run_dir / "edits.json", keys, n_frames=scene.n_frames,
                n_vertices=scene.n_vertices, boundaries=scene.boundaries.tolist(),
            )  # fmt: skip
    save_npz_atomic(run_dir / "scene.npz", original=np.asarray(X, np.float32),
                    faces=dense["faces"], marker_vertex=dense["marker_vertex"],
                    marker_names=np.asarray(names), markers=M, rate=np.float64(rate),
                    gamma=np.float64(g), **scene_to_arrays(scene))  # fmt: skip


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


def _head_outputs(cfg: Config, run_dir: Path, M, Me, names, rate: float, keys) -> dict:
    """The real head (a blend-shape rig, the ICT Face Model by default) driven by the
    *edited* markers: bound at the capture's neutral frame (`_neutral`), per-frame
    ARKit-named weights solved (the edited take warm-started from the unedited weights)
    (`fxspace.face`), written as ``head.glb`` (morph targets + the weight animation) and
    ``head_weights.csv``; the unedited solve and the rigid-only residual beside it."""
    from fxspace.face import (
        bind_markers,
        read_rig,
        solve_weights,
        write_rig_gltf,
        write_weights_csv,
    )

    print("[reconstruction] the head: binding the markers, solving the weights …", flush=True)
    rig = read_rig(_head_path(cfg))
    b = bind_markers(rig, _neutral(cfg, M), names, units="mm")
    kw = {"names": list(names), "units": "mm"}
    plain = solve_weights(rig, b, M, **kw)
    # the edited take starts from the unedited weights (a warm start: the edit moves a
    # few markers in a few frames)
    init = np.nan_to_num(np.asarray(plain.weights), nan=0.0)
    edited = solve_weights(rig, b, Me, init=init, **kw)
    rigid = solve_weights(rig, b, M, expressions=False, **kw)
    for what, sol in (("unedited", plain), ("edited", edited)):
        for line in sol.notes:
            print(f"[reconstruction] the head, {what} take: {line}", flush=True)
    write_rig_gltf(run_dir / "head.glb", rig, edited.weights, fps=rate, name="edited")
    write_weights_csv(run_dir / "head_weights.csv", edited.weights, rig.names, fps=rate)
    f = keys[0].frame
    dw = np.abs(np.asarray(edited.weights[f]) - np.asarray(plain.weights[f]))
    mm = np.asarray(b.distance) / b.scale
    return {
        "rig": cfg.head, "files": ["head.glb", "head_weights.csv"],
        "n_shapes": rig.num_shapes, "n_vertices": rig.num_vertices,
        "binding_distance_median": float(np.median(mm)),
        "binding_distance_max": float(mm.max()),
        "residual_mean": float(np.nanmean(np.asarray(plain.residual))),
        "residual_rigid_only_mean": float(np.nanmean(np.asarray(rigid.residual))),
        "converged_fraction": float(np.mean(np.asarray(plain.converged))),
        "poor_fit_frames": [int(i) for i in np.flatnonzero(
            np.asarray(plain.result == RESULTS.poor_fit))],
        "poor_fit_frames_edited": [int(i) for i in np.flatnonzero(
            np.asarray(edited.result == RESULTS.poor_fit))],
        "fit_notes": list(plain.notes), "fit_notes_edited": list(edited.notes),
        "solve_steps_unedited": int(np.sum(np.asarray(plain.num_steps))),
        "solve_steps_edited_warm": int(np.sum(np.asarray(edited.num_steps))),
        "edit_frame": int(f), "edit_weight_change_max": float(dw.max()),
        "edit_weight_changed_most": rig.names[int(np.argmax(dw))],
        "units": "mm (residuals and binding distances)",
    }  # fmt: skip


def _neutral(cfg: Config, M: np.ndarray) -> np.ndarray:
    """``(M, 3)`` the frame the head is bound to, in mm: the capture's first frame with
    every marker seen (AnimFace: its neutral face at the start), not the first frame of
    the analysed window (``start``), which may hold an expression: bound there, every
    shape's delta is taken from that expression (on the cheeks take from frame 300 the
    solved residual is 0.54 of the rigid-only one, bound at the neutral 0.40)."""
    from fxspace.io import read_markers

    if cfg.file == SYNTHETIC:
        return M[0]
    seq = read_markers(_path(cfg.file))
    seq = seq.to_units("mm") if seq.units != "mm" else seq
    P = np.asarray(seq.positions, np.float64)
    ok = np.flatnonzero(np.all(np.isfinite(P), axis=(1, 2)))
    return P[ok[0]] if len(ok) else M[0]


def _edit_marker(cfg: Config, names) -> int:
    """The index of ``edit_marker`` among the capture's markers (exact, else ignoring
    case; the default ``Mouth_Lend`` is the synthetic face's ``mouth_corner_l``); an
    unknown name is refused, listing the near matches."""
    import difflib

    names = [str(n) for n in names]
    want = cfg.edit_marker
    if cfg.file == SYNTHETIC and want == Config.edit_marker:
        want = "mouth_corner_l"  # the same marker, the synthetic face's name
    if want in names:
        return names.index(want)
    low = [n.lower() for n in names]
    if want.lower() in low:
        return low.index(want.lower())
    near = difflib.get_close_matches(want.lower(), low, n=4, cutoff=0.5)
    near = [names[low.index(n)] for n in near]
    raise ConfigError(
        f"edit_marker {cfg.edit_marker!r} is not a marker of {cfg.file}"
        + (f"; did you mean {near}?" if near else "")
        + f" (its markers: {names[:8]}{' …' if len(names) > 8 else ''})"
    )


def _edit_keys(cfg: Config, scene, names, mv, si: int) -> list:
    """The demonstration edit: a key at the middle of the most complex segment moving the
    region under ``edit_marker`` by ``edit_offset_mm`` (mm: the capture is read in mm;
    the editor's saved keys)."""
    a, b = segments_from_boundaries(scene.boundaries)[si]
    vi = int(mv[_edit_marker(cfg, names)])
    return [FaceKey(a + (b - a) // 2, vi, tuple(float(v) for v in cfg.edit_offset_mm))]


def _write_outputs(ctx: dict) -> dict:
    """The edit (``edits.json``), ``scene.npz`` for the editor, the edited sequence, the
    character's glTF, and the figures."""
    from fxspace.io import MarkerSequence, read_gltf_morph, write_gltf_morph, write_trc

    cfg, run_dir, scene, X, M = ctx["cfg"], ctx["run_dir"], ctx["scene"], ctx["X"], ctx["M"]
    names, dense, keys = ctx["names"], ctx["dense"], ctx["keys"]
    mv = dense["marker_vertex"]
    vi = keys[0].vertex
    Xh = np.asarray(reconstruct_scene(scene))
    Xe = edited_vertices(scene, keys)
    moved = np.linalg.norm(Xe - Xh, axis=2).max(0) > 1e-9
    _editor_files(run_dir, X, M, names, ctx["rate"], dense, scene, ctx["g"], keys)
    Me = M + (Xe - Xh)[:, mv]
    save_npz_atomic(run_dir / "edited_sequence.npz", vertices=Xe.astype(np.float32),
                    faces=dense["faces"], boundaries=scene.boundaries, markers=Me)  # fmt: skip
    write_trc(run_dir / "edited_markers.trc", MarkerSequence(Me, names, ctx["rate"], "mm"))
    out = {"keys": keys, "moved": int(moved.sum()), "Xe": Xe, "vi": vi}
    if cfg.head and cfg.file != SYNTHETIC:
        out["head"] = _head_outputs(cfg, run_dir, M, Me, names, ctx["rate"], keys)
    if ctx["ch"] is not None:
        Y = ctx["ch"]["vertices"]
        p = write_gltf_morph(run_dir / "character.glb", Y, ctx["ch"]["faces"], ctx["rate"],
                             name="character")  # fmt: skip
        back = read_gltf_morph(p)
        # measured (issue 47.7): the edit moved the driven face, and the file read back
        # holds the edited face — its vertices are the edited ones to well under the edit
        reload_diff = float(np.abs(back.vertices - Y).max())
        edit_max = float(ctx["ch"]["edit_moved"].max())
        out["character"] = {
            "file": p.name, "n_vertices": int(Y.shape[1]), "n_frames": int(Y.shape[0]),
            "source": cfg.character,
            "reloaded_max_abs_diff": reload_diff,
            "reloaded_fps": back.fps,
            "carries_edits": bool(edit_max > 1e-6 and reload_diff < 0.1 * edit_max),
            "edit_moved_vertices": int((ctx["ch"]["edit_moved"] > 1e-9).sum()),
            "edit_moved_max": float(ctx["ch"]["edit_moved"].max()),
        }  # fmt: skip
    _figures(ctx, out)
    return out


def _figures(ctx: dict, out: dict) -> None:
    from fxspace.plot import (
        plot_control_points,
        plot_reconstruction_frames,
        plot_scene_errors,
        plot_segmentation,
    )

    run_dir, sg, scene, errs, si = ctx["run_dir"], ctx["sg"], ctx["scene"], ctx["errs"], ctx["si"]
    seg = Segmentation(sg["boundaries"], sg["summary"], sg["fit"], float(sg["lam"]),
                       sg["jump_energy"])  # fmt: skip
    save_figure_atomic(plot_segmentation(seg, rate=ctx["rate"]), run_dir / "segmentation.png")
    save_figure_atomic(plot_scene_errors(errs, scene.boundaries), run_dir / "scene_errors.png")
    a, b = segments_from_boundaries(scene.boundaries)[si]
    S, model = ctx["X"][a : b + 1], scene.segments[si]
    save_figure_atomic(plot_control_points(np.asarray(S[0]), np.asarray(model.labels)),
                       run_dir / "control_points.png")  # fmt: skip
    T = S.shape[0]
    fr = (T - 1) // 2
    L = linear_interpolation(S[0], S[-1], T)
    names, M = ctx["names"], ctx["M"]
    up = None
    if "ForeHead_M" in names and "Chin" in names:
        up = M[0][names.index("ForeHead_M")] - M[0][names.index("Chin")]
    fig = plot_reconstruction_frames(
        [S[fr], L[fr], reconstruct(model)[fr], reconstruct(ctx["fitted"])[fr], out["Xe"][a + fr]],
        ["original", f"linear (E={float(errs.linear[si]):.3g})",
         f"ours k-means (E={float(errs.model[si]):.3g})",
         f"ours fitted (E={float(ctx['rf']['error']):.3g})", "edited (smirk)"],
        faces=ctx["dense"]["faces"], reference=np.asarray(S[fr]), up=up,
    )  # fmt: skip
    save_figure_atomic(fig, run_dir / "reconstruction.png")


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
