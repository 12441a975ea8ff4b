"""The reconstruction experiment's stages besides the dense surface and the sweep
(`fxspace.pipelines.reconstruction`): the segmentation, the whole-scene pipeline, the
driven character and the skinned glTF source."""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fxspace.config import ConfigError
from fxspace.controlpoints import (
    character,
    compression_ratio,
    drive_character,
    fit_control_points,
    fit_scene,
    reconstruct,
    reconstruct_scene,
    reconstruction_error,
    scene_to_arrays,
    segment_motion,
    segments_from_boundaries,
    standin_character,
)
from fxspace.data import data_path
from fxspace.pipelines._reconstruction_config import Config, _path


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
