"""The control-point editor's state and actions (Hirose & Higuchi §1–2), without any UI.

The scene (a dense face sequence) is modelled by control points per segment
(`fxspace.fit_scene`). The animator scrubs to any frame (segment boundaries included),
moves a control point — a key anchored on the face, ``FaceKey(frame, vertex, offset)``,
whose vertex stands for the control point's region — sees the region follow through the
blend weights, reviews, re-edits, undoes or redoes; the keys are saved as data in the run
folder (``edits.json``) after every change and replayed on the next start (old
per-segment files are converted). The paper's knobs (segments, control points, kernel
width) re-fit the scene and the keys stay, since they live on the face, not on a segment.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from fxspace.controlpoints import (
    FaceKey,
    SceneModel,
    anchor_offsets,
    anchor_vertex,
    check_face_keys,
    convert_keys,
    edit_displacements,
    edited_control_positions,
    fit_scene,
    linear_scene,
    load_edits,
    reconstruct_scene,
    save_edits,
    scene_errors,
    scene_from_arrays,
    scene_to_arrays,
    segment_of_frame,
)
from fxspace.errors import FxspaceError

__all__ = ["EditorData", "EditorController", "load_editor_data", "save_editor_data", "MODES"]

Mode = Literal["original", "linear", "control points", "edited"]
MODES: tuple[str, ...] = ("edited", "control points", "linear", "original")
_SCENE = "scene.npz"
_REFIT = "editor_scene.npz"
_EDITS = "edits.json"


@dataclass(frozen=True)
class EditorData:
    """What the editor works on: the dense scene, its triangles, the fitted model, where
    to save (``run_dir``; None: nothing is saved)."""

    original: np.ndarray  # (T, N, 3)
    faces: np.ndarray  # (F, 3)
    scene: SceneModel
    rate: float = 30.0
    gamma: float | None = None
    run_dir: Path | None = None
    marker_vertex: np.ndarray | None = None
    marker_names: tuple[str, ...] = ()
    markers: np.ndarray | None = None  # (T, M, 3) the capture, when the run kept it


def save_editor_data(run_dir: str | Path, data: EditorData, name: str = _SCENE) -> Path:
    """Write ``scene.npz`` (the dense scene, triangles and model) into ``run_dir``."""
    from fxspace.runs import save_npz_atomic

    extra = {} if data.marker_vertex is None else {"marker_vertex": data.marker_vertex}
    if data.markers is not None:
        extra["markers"] = np.asarray(data.markers, np.float64)
    if data.marker_names:
        extra["marker_names"] = np.asarray(data.marker_names)
    return save_npz_atomic(
        Path(run_dir) / name, original=np.asarray(data.original, np.float32), faces=data.faces,
        rate=np.float64(data.rate), gamma=np.float64(np.nan if data.gamma is None else data.gamma),
        **extra, **scene_to_arrays(data.scene),
    )  # fmt: skip


def load_editor_data(target: str | Path) -> EditorData:
    """`EditorData` of a reconstruction run folder (``scene.npz``; a re-fit saved
    by the editor, ``editor_scene.npz``, wins), or of a config's default run folder
    (``runs/<config stem>``)."""
    p = Path(target)
    if p.is_file():
        run = Path("runs") / p.stem
        if not (run / _SCENE).is_file():
            raise FxspaceError(
                f"{target}: run it first (fxspace run {target}); the editor opens its run "
                f"folder {run}"
            )
        p = run
    src = p / _REFIT if (p / _REFIT).is_file() else p / _SCENE
    if not src.is_file():
        raise FxspaceError(
            f"{p}: no {_SCENE}; run the reconstruction experiment first "
            "(fxspace run configs/reconstruction.toml)"
        )
    z = np.load(src)
    g = float(z["gamma"]) if "gamma" in z else float("nan")
    return EditorData(
        original=np.asarray(z["original"], np.float32), faces=np.asarray(z["faces"]),
        scene=scene_from_arrays(z), rate=float(z["rate"]) if "rate" in z else 30.0,
        gamma=None if np.isnan(g) else g, run_dir=p,
        marker_vertex=np.asarray(z["marker_vertex"]) if "marker_vertex" in z else None,
        marker_names=tuple(str(s) for s in z["marker_names"]) if "marker_names" in z else (),
        markers=np.asarray(z["markers"], np.float64) if "markers" in z else None,
    )  # fmt: skip


class EditorController:
    """State: ``frame``, ``mode`` (one of `MODES`), ``keys`` (the edit history, `FaceKey`s),
    ``redo_keys``, ``playing``/``loop``, ``message``; sequences are cached per mode."""

    def __init__(self, data: EditorData, face=None):
        self.data = data
        self.face = face  # the head shown (`RigFace`, `DenseFace`) or None: the surface
        self.frame = 0
        self.mode: str = "edited"
        self.keys: list[FaceKey] = []
        self.redo_keys: list[FaceKey] = []
        self.playing = False
        self.loop = True
        self.message = "scrub to a frame and drag a control point"
        self._cache: dict[str, np.ndarray] = {}
        self._lock = threading.RLock()
        if data.run_dir is not None and (data.run_dir / _EDITS).is_file():
            self.message = self._load_keys(data.run_dir / _EDITS)

    def _load_keys(self, path: Path) -> str:
        """Replay ``edits.json`` (per-segment files of older runs are converted)."""
        try:
            keys, meta = load_edits(path)
        except FxspaceError as e:
            return f"{_EDITS} ignored: {e}"
        scene = self.data.scene
        legacy = any(not isinstance(k, FaceKey) for k in keys)
        if legacy and list(meta.get("boundaries", scene.boundaries.tolist())) != (
            scene.boundaries.tolist()
        ):
            return f"{_EDITS} ignored: it belongs to another segmentation"
        try:
            self.keys = check_face_keys(scene, convert_keys(scene, keys))
        except FxspaceError as e:
            return f"{_EDITS} ignored: {e}"
        if legacy:
            self._save()
            return f"replayed {len(keys)} edit keys from {_EDITS} (converted to keys on the face)"
        return f"replayed {len(keys)} edit keys from {_EDITS}"

    # -- sequences -----------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.data.original.shape[0])

    def sequence(self, mode: str | None = None) -> np.ndarray:
        """``(T, N, 3)`` frames of ``mode`` (default the shown one)."""
        mode = self.mode if mode is None else mode
        if mode not in MODES:
            raise FxspaceError(f"mode must be one of {MODES}; got {mode!r}")
        with self._lock:
            if mode not in self._cache:
                d = self.data
                if mode == "original":
                    X = d.original
                elif mode == "linear":
                    X = linear_scene(d.original, d.scene.boundaries)
                elif mode == "control points":
                    X = reconstruct_scene(d.scene)
                else:
                    X = self.sequence("control points") + edit_displacements(d.scene, self.keys)
                self._cache[mode] = np.asarray(X, np.float32)
            return self._cache[mode]

    def vertices(self, frame: int | None = None) -> np.ndarray:
        return self.sequence()[self.frame if frame is None else int(frame)]

    def controls(self, frame: int | None = None) -> tuple[int, np.ndarray]:
        """``(segment, (c, 3))`` control points (edited) at ``frame``."""
        f = self.frame if frame is None else int(frame)
        return edited_control_positions(self.data.scene, self.keys, f)

    def key_frames(self) -> list[int]:
        """Frames that hold a key (sorted, once each): what the timeline marks."""
        return sorted({int(k.frame) for k in self.keys})

    def _invalidate(self) -> None:
        self._cache.pop("edited", None)
        self._cache.pop("head:edited", None)

    # -- the head ------------------------------------------------------------------------
    @property
    def has_rig(self) -> bool:
        """Whether the head is a blend-shape rig (weights to show and export)."""
        return self.face is not None and hasattr(self.face, "rig")

    def head_markers(self, V: np.ndarray | None = None, frame: int | None = None,
                     mode: str | None = None) -> np.ndarray:  # fmt: skip
        """``(M, 3)`` markers that drive the head at ``frame`` when the shown surface there
        is ``V`` (default: the shown mode's): the capture's markers moved as the surface
        under them moved — from the model (``"control points"``) in the edited mode, so
        the edited head is the capture plus the animator's edits (what the run's
        ``head.glb`` carries), from the capture in the other modes."""
        d = self.data
        if d.markers is None or d.marker_vertex is None:
            raise FxspaceError("this run kept no markers: the head cannot be driven")
        mode = self.mode if mode is None else mode
        t = self.frame if frame is None else int(frame)
        V = self.sequence(mode)[t] if V is None else np.asarray(V)
        ref = self.sequence("control points" if mode == "edited" else "original")[t]
        mv = np.asarray(d.marker_vertex)
        return np.asarray(d.markers[t], np.float64) + (V - ref)[mv].astype(np.float64)

    def head_solve(self, mode: str | None = None):
        """The rig's `FaceSolve` over the whole sequence of ``mode`` (cached; all frames in
        one batch, with the temporal term), or None when the head is not a rig."""
        if not self.has_rig:
            return None
        mode = self.mode if mode is None else mode
        with self._lock:
            key = f"head:{mode}"
            if key not in self._cache:
                d = self.data
                ref = "control points" if mode == "edited" else "original"
                mv = np.asarray(d.marker_vertex)
                moved = self.sequence(mode)[:, mv] - self.sequence(ref)[:, mv]
                markers = np.asarray(d.markers, np.float64) + moved
                if mode == "edited":  # warm start from the unedited model's weights
                    from fxspace.face import solve_weights

                    base = self.head_solve("control points")
                    init = np.nan_to_num(np.asarray(base.weights), nan=0.0)
                    self._cache[key] = solve_weights(self.face.rig, self.face.binding,
                                                     markers, init=init)  # fmt: skip
                else:
                    self._cache[key] = self.face.solve(markers)
            return self._cache[key]

    def head_weights(self, mode: str | None = None) -> np.ndarray | None:
        """``(T, K)`` expression weights of the whole sequence (`head_solve`), or None."""
        s = self.head_solve(mode)
        return None if s is None else np.asarray(s.weights)

    def _save(self) -> None:
        if self.data.run_dir is not None:
            save_edits(self.data.run_dir / _EDITS, self.keys, n_frames=self.n_frames,
                       n_vertices=int(self.data.original.shape[1]),
                       boundaries=self.data.scene.boundaries.tolist())  # fmt: skip

    # -- actions -------------------------------------------------------------------------
    def set_frame(self, frame: int) -> None:
        self.frame = int(np.clip(int(frame), 0, self.n_frames - 1))

    def set_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise FxspaceError(f"mode must be one of {MODES}; got {mode!r}")
        self.mode = mode

    def anchor_of(self, control: int, frame: int | None = None) -> int:
        """The vertex a drag of ``control`` (of the segment holding ``frame``) keys: an
        anchor already keyed inside that control point's cluster (the latest), else the
        control point's own `anchor_vertex`."""
        f = self.frame if frame is None else int(frame)
        s, _ = segment_of_frame(self.data.scene.boundaries, f)
        W = np.asarray(self.data.scene.segments[s].weights)
        for k in reversed(self.keys):
            if int(np.argmax(W[k.vertex])) == int(control):
                return int(k.vertex)
        return anchor_vertex(self.data.scene, s, int(control), f)

    def _key_for(self, control: int, position) -> FaceKey | None:
        s, C = self.controls()
        if not 0 <= int(control) < len(C):
            self.message = (
                f"control point {control} does not exist in segment {s} (0 … {len(C) - 1})"
            )
            return None
        p = np.asarray(position, np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            self.message = f"position must be 3 finite numbers; got {p.tolist()}"
            return None
        v = self.anchor_of(control)
        now = anchor_offsets(self.keys, self.data.scene.boundaries).get(v)
        cur = np.zeros(3) if now is None else now[self.frame]
        off = cur + (p - C[int(control)])
        return FaceKey(self.frame, v, tuple(float(x) for x in off))  # type: ignore[arg-type]

    def move_control(self, control: int, position) -> bool:
        """Move control point ``control`` (of the segment holding the current frame) to
        ``position`` (scene units) at the current frame: writes a key, replays, saves."""
        with self._lock:
            k = self._key_for(control, position)
            if k is None:
                return False
            self.keys.append(k)
            self.redo_keys = []
            self._invalidate()
            self._save()
            self.message = (
                f"key at frame {k.frame}: control point {control} (vertex {k.vertex}), "
                f"offset {np.round(k.offset, 2).tolist()}"
            )
            return True

    def nudge_control(self, control: int, delta) -> bool:
        """Move control point ``control`` by ``delta`` from where it is now (edited)."""
        _, C = self.controls()
        if not 0 <= int(control) < len(C):
            self.message = f"control point {control} does not exist here (0 … {len(C) - 1})"
            return False
        d = np.asarray(delta, np.float64).reshape(-1)
        if d.shape != (3,) or not np.all(np.isfinite(d)):
            self.message = f"offset must be 3 finite numbers; got {d.tolist()}"
            return False
        return self.move_control(control, C[int(control)] + d)

    def preview(self, control: int, position) -> np.ndarray | None:
        """The current frame's vertices if control ``control`` were at ``position`` (no key
        written: the live view while dragging); equal to the frame after `move_control`."""
        k = self._key_for(control, position)
        if k is None:
            return None
        D = edit_displacements(self.data.scene, [*self.keys, k], [self.frame])[0]
        return self.sequence("control points")[self.frame].astype(np.float64) + D

    def undo(self) -> None:
        with self._lock:
            if not self.keys:
                self.message = "nothing to undo"
                return
            k = self.keys.pop()
            self.redo_keys.append(k)
            self._invalidate()
            self._save()
            self.message = f"undone: key at frame {k.frame} (vertex {k.vertex})"

    def redo(self) -> None:
        with self._lock:
            if not self.redo_keys:
                self.message = "nothing to redo"
                return
            k = self.redo_keys.pop()
            self.keys.append(k)
            self._invalidate()
            self._save()
            self.message = f"redone: key at frame {k.frame} (vertex {k.vertex})"

    def clear_edits(self) -> None:
        with self._lock:
            self.redo_keys = list(reversed(self.keys))
            self.keys = []
            self._invalidate()
            self._save()
            self.message = "edits cleared (redo brings them back)"

    def refit(self, n_segments: int, n_clusters: int, gamma: float | None, seed: int = 0) -> None:
        """Re-fit the scene with the paper's knobs (saved as ``editor_scene.npz``); the
        keys live on the face, so they stay and are replayed on the new model."""
        import jax

        with self._lock:
            fit = fit_scene(
                self.data.original, int(n_clusters), n_segments=int(n_segments),
                gamma=gamma, key=jax.random.PRNGKey(seed), n_init=10,
            )  # fmt: skip
            self.data = replace(self.data, scene=fit.model, gamma=gamma)
            self._cache.clear()
            if self.data.run_dir is not None:
                save_editor_data(self.data.run_dir, self.data, _REFIT)
            self._save()
            e = scene_errors(self.data.original, fit.model)
            self.message = (
                f"re-fitted: {len(fit.model.boundaries) - 1} segments, {n_clusters} control "
                f"points, γ={gamma}: ratio {e.ratio_scene:.4f} vs linear; "
                f"{len(self.keys)} edit keys kept"
            )

    def step(self) -> int:
        """Advance playback one frame (wrapping when ``loop``)."""
        with self._lock:
            nxt = self.frame + 1
            if nxt >= self.n_frames:
                if not self.loop:
                    self.playing = False
                    return self.frame
                nxt = 0
            self.frame = nxt
            return self.frame

    def export(self, out_dir: str | Path, fmt: str = "gltf") -> list[Path]:
        """Write the edited sequence (``"gltf"``: one .glb with morph targets; ``"obj"`` /
        ``"ply"``: a file per frame) and the control-point data (``control_points.npz`` +
        ``edits.json``); with a rig head, also the rig with the edited sequence's weights
        animated (``head.glb``: morph targets + weight animation) and the weights per frame
        (``head_weights.csv``, the shapes' names as columns)."""
        from fxspace.io import write_gltf_morph, write_obj_sequence, write_ply_sequence
        from fxspace.runs import save_npz_atomic

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        V = self.sequence("edited")
        if fmt == "gltf":
            paths = [write_gltf_morph(out / "edited.glb", V, self.data.faces, self.data.rate)]
        elif fmt == "obj":
            paths = write_obj_sequence(out / "obj", V, self.data.faces)
        elif fmt == "ply":
            paths = write_ply_sequence(out / "ply", V, self.data.faces)
        else:
            raise FxspaceError(f"fmt must be 'gltf', 'obj' or 'ply'; got {fmt!r}")
        paths.append(save_npz_atomic(out / "control_points.npz",
                                     **scene_to_arrays(self.data.scene)))  # fmt: skip
        paths.append(save_edits(out / _EDITS, self.keys, n_frames=self.n_frames))
        if self.has_rig:  # the character carries the edits: the rig's weights, animated
            from fxspace.face import write_rig_gltf, write_weights_csv

            W = self.head_weights("edited")
            rig = self.face.rig
            paths.append(write_rig_gltf(out / "head.glb", rig, W, fps=self.data.rate,
                                        name="edited"))  # fmt: skip
            paths.append(write_weights_csv(out / "head_weights.csv", W, rig.names,
                                           fps=self.data.rate))  # fmt: skip
        self.message = f"exported {len(paths)} files to {out}"
        return [Path(p) for p in paths]

    def status(self) -> dict:
        """What the status panel shows, as data (the editor's view renders it): the
        ``frame`` of ``n_frames``, its ``segment`` and that segment's ``span`` (first and
        last frame), the ``boundaries``, the shown ``mode``, the number of edit ``keys``
        and their ``key_frames``, ``edit_diff`` (largest edited-minus-model coordinate at
        this frame), ``playing`` and the last ``message``."""
        s, _ = segment_of_frame(self.data.scene.boundaries, self.frame)
        b = np.asarray(self.data.scene.boundaries)
        diff = float(np.abs(self.sequence("edited")[self.frame]
                            - self.sequence("control points")[self.frame]).max())  # fmt: skip
        return {
            "frame": int(self.frame),
            "n_frames": int(self.n_frames),
            "segment": int(s),
            "span": (int(b[s]), int(b[s + 1])),
            "boundaries": b.astype(int).tolist(),
            "mode": self.mode,
            "keys": len(self.keys),
            "key_frames": [int(f) for f in self.key_frames()],
            "edit_diff": diff,
            "playing": bool(self.playing),
            "message": self.message,
        }
