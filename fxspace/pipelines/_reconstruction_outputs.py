"""The reconstruction experiment's outputs (`fxspace.pipelines.reconstruction`): the
demonstration edit, ``scene.npz`` and ``edits.json`` for the editor, the edited sequence,
the head and the character as glTF, and the figures (each drawn by `fxspace.plot`, saved
here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace.controlpoints import (
    FaceKey,
    Segmentation,
    edited_vertices,
    linear_interpolation,
    reconstruct,
    reconstruct_scene,
    save_edits,
    scene_to_arrays,
    segments_from_boundaries,
)
from fxspace.pipelines._reconstruction_config import (
    SYNTHETIC,
    Config,
    _edit_marker,
    _head_path,
    _neutral,
)
from fxspace.results import RESULTS
from fxspace.runs import save_figure_atomic, save_npz_atomic


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
