"""The control-point editor's state and actions (Hirose & Higuchi §1–2), without any UI.

The scene (a dense face sequence) is modelled by control points per segment
(:func:`fxspace.fit_scene`). The animator scrubs to a frame, moves a control point (a key
``(segment, control, frame, offset)``, :class:`fxspace.EditKey`), sees the region follow
through the blend weights, reviews, re-edits or undoes; the keys are saved as data in the
run folder (``edits.json``) after every change and replayed on the next start. The paper's
knobs (segments, control points, kernel width) re-fit the scene.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from fxspace.controlpoints import (
    EditKey,
    SceneModel,
    apply_edits,
    control_positions,
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


def save_editor_data(run_dir: str | Path, data: EditorData, name: str = _SCENE) -> Path:
    """Write ``scene.npz`` (the dense scene, triangles and model) into ``run_dir``."""
    from fxspace.runs import save_npz_atomic

    extra = {} if data.marker_vertex is None else {"marker_vertex": data.marker_vertex}
    if data.marker_names:
        extra["marker_names"] = np.asarray(data.marker_names)
    return save_npz_atomic(
        Path(run_dir) / name, original=np.asarray(data.original, np.float32), faces=data.faces,
        rate=np.float64(data.rate), gamma=np.float64(np.nan if data.gamma is None else data.gamma),
        **extra, **scene_to_arrays(data.scene),
    )  # fmt: skip


def load_editor_data(target: str | Path) -> EditorData:
    """:class:`EditorData` of a reconstruction run folder (``scene.npz``; a re-fit saved
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
    )  # fmt: skip


class EditorController:
    """State: ``frame``, ``mode`` (one of :data:`MODES`), ``keys`` (the edit history),
    ``playing``/``loop``, ``message``; sequences are cached per mode."""

    def __init__(self, data: EditorData):
        self.data = data
        self.frame = 0
        self.mode: str = "edited"
        self.keys: list[EditKey] = []
        self.playing = False
        self.loop = True
        self.message = "scrub to a frame and move a control point"
        self._cache: dict[str, np.ndarray] = {}
        self._edited: SceneModel | None = None
        self._lock = threading.RLock()
        if data.run_dir is not None and (data.run_dir / _EDITS).is_file():
            keys, meta = load_edits(data.run_dir / _EDITS)
            if list(meta.get("boundaries", data.scene.boundaries.tolist())) == (
                data.scene.boundaries.tolist()
            ):
                try:
                    apply_edits(data.scene, keys)
                    self.keys = keys
                    self.message = f"replayed {len(keys)} edit keys from {_EDITS}"
                except FxspaceError as e:
                    self.message = f"{_EDITS} ignored: {e}"
            else:
                self.message = f"{_EDITS} ignored: it belongs to another segmentation"

    # -- sequences -----------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.data.original.shape[0])

    def edited_scene(self) -> SceneModel:
        if self._edited is None:
            self._edited = apply_edits(self.data.scene, self.keys)
        return self._edited

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
                    X = reconstruct_scene(self.edited_scene())
                self._cache[mode] = np.asarray(X, np.float32)
            return self._cache[mode]

    def vertices(self, frame: int | None = None) -> np.ndarray:
        return self.sequence()[self.frame if frame is None else int(frame)]

    def controls(self, frame: int | None = None) -> tuple[int, np.ndarray]:
        """``(segment, (c, 3))`` control points (edited) at ``frame``."""
        return control_positions(self.edited_scene(), self.frame if frame is None else frame)

    def _invalidate(self) -> None:
        self._edited = None
        self._cache.pop("edited", None)

    def _save(self) -> None:
        if self.data.run_dir is not None:
            save_edits(self.data.run_dir / _EDITS, self.keys,
                       boundaries=self.data.scene.boundaries.tolist())  # fmt: skip

    # -- actions -------------------------------------------------------------------------
    def set_frame(self, frame: int) -> None:
        self.frame = int(np.clip(int(frame), 0, self.n_frames - 1))

    def set_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise FxspaceError(f"mode must be one of {MODES}; got {mode!r}")
        self.mode = mode

    def _key_for(self, control: int, position) -> EditKey | None:
        s, t = segment_of_frame(self.data.scene.boundaries, self.frame)
        T = int(self.data.scene.boundaries[s + 1] - self.data.scene.boundaries[s]) + 1
        if t == 0 or t == T - 1:
            self.message = (
                f"frame {self.frame} is a segment boundary (a stored key frame): move to an "
                "in-between frame to edit"
            )
            return None
        c = self.data.scene.segments[s].controls.shape[0]
        if not 0 <= int(control) < c:
            self.message = f"control point {control} does not exist in segment {s} (0 … {c - 1})"
            return None
        base = np.asarray(self.data.scene.segments[s].controls[int(control), t], np.float64)
        off = np.asarray(position, np.float64).reshape(3) - base
        return EditKey(s, int(control), self.frame, tuple(float(v) for v in off))  # type: ignore[arg-type]

    def move_control(self, control: int, position) -> bool:
        """Move control point ``control`` of the current frame's segment to ``position``
        (scene units) at the current frame: writes a key, re-plays, saves."""
        with self._lock:
            k = self._key_for(control, position)
            if k is None:
                return False
            self.keys.append(k)
            self._invalidate()
            self._save()
            self.message = (
                f"key: control point {k.control} of segment {k.segment} at frame {k.frame}, "
                f"offset {np.round(k.offset, 2).tolist()}"
            )
            return True

    def nudge_control(self, control: int, delta) -> bool:
        """Move control point ``control`` by ``delta`` from where it is now (edited)."""
        _, C = self.controls()
        if not 0 <= int(control) < len(C):
            self.message = f"control point {control} does not exist here (0 … {len(C) - 1})"
            return False
        return self.move_control(control, C[int(control)] + np.asarray(delta, np.float64))

    def preview(self, control: int, position) -> np.ndarray | None:
        """The current frame's vertices if control ``control`` were at ``position`` (no key
        written: the live view while dragging)."""
        k = self._key_for(control, position)
        if k is None:
            return None
        s, t = segment_of_frame(self.data.scene.boundaries, self.frame)
        _, C = self.controls()
        w = np.asarray(self.data.scene.segments[s].weights[:, int(control)], np.float64)
        edited = self.sequence("edited")[self.frame].astype(np.float64)
        return edited + w[:, None] * (np.asarray(position) - C[int(control)])[None, :]

    def undo(self) -> None:
        with self._lock:
            if not self.keys:
                self.message = "nothing to undo"
                return
            k = self.keys.pop()
            self._invalidate()
            self._save()
            self.message = f"undone: key of control point {k.control} at frame {k.frame}"

    def clear_edits(self) -> None:
        with self._lock:
            self.keys = []
            self._invalidate()
            self._save()
            self.message = "edits cleared"

    def refit(self, n_segments: int, n_clusters: int, gamma: float | None, seed: int = 0) -> None:
        """Re-fit the scene with the paper's knobs; the old keys belong to the old model and
        are dropped (the re-fit model is saved as ``editor_scene.npz``)."""
        import jax

        with self._lock:
            fit = fit_scene(
                self.data.original, int(n_clusters), n_segments=int(n_segments),
                gamma=gamma, key=jax.random.PRNGKey(seed), n_init=10,
            )  # fmt: skip
            self.data = replace(self.data, scene=fit.model, gamma=gamma)
            self.keys = []
            self._cache.clear()
            self._invalidate()
            if self.data.run_dir is not None:
                save_editor_data(self.data.run_dir, self.data, _REFIT)
            self._save()
            e = scene_errors(self.data.original, fit.model)
            self.message = (
                f"re-fitted: {len(fit.model.boundaries) - 1} segments, {n_clusters} control "
                f"points, γ={gamma}: ratio {e.ratio_scene:.4f} vs linear; edits cleared"
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
        ``edits.json``)."""
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
                                     **scene_to_arrays(self.edited_scene())))  # fmt: skip
        paths.append(save_edits(out / _EDITS, self.keys,
                                boundaries=self.data.scene.boundaries.tolist()))  # fmt: skip
        self.message = f"exported {len(paths)} files to {out}"
        return [Path(p) for p in paths]

    def status(self) -> str:
        s, t = segment_of_frame(self.data.scene.boundaries, self.frame)
        b = self.data.scene.boundaries
        diff = float(np.abs(self.sequence("edited")[self.frame]
                            - self.sequence("control points")[self.frame]).max())  # fmt: skip
        return (
            f"**Frame {self.frame}** of {self.n_frames - 1} — segment {s} "
            f"(frames {int(b[s])}–{int(b[s + 1])})  \n"
            f"Showing: {self.mode}  \n"
            f"Edit keys: {len(self.keys)}  \n"
            f"Edited vs model here: {diff:.3f} max  \n"
            f"{'Playing' if self.playing else 'Paused'}  \n"
            f"_{self.message}_"
        )
