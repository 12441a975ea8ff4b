"""Whole-scene control points (Hirose & Higuchi §1–2): segment the whole capture, one
control-point model per segment, stitched at the shared boundary frames.

With boundaries ``0 = b_0 < … < b_s = T − 1`` (`fxspace.segment_motion`), segment
``i`` covers frames ``b_i … b_{i+1}`` inclusive; its model stores its first and last frame
(the scene's key frames) and ``c`` control-point trajectories. A boundary frame is the
last frame of one segment and the first of the next, stored once, so the stitched
sequence is continuous there by construction (both models reproduce that frame
exactly). The baseline is the scene's linear interpolation between the same key frames
(piecewise linear), and the paper's error (eq. (1)) is reported per segment and for the
scene:

    E_scene = Σ_t Σ_i ‖x_i(t) − x̂_i(t)‖²  (each frame once; 0 at the key frames).

Storage: the ``s + 1`` key frames (``(s+1)·N·3``), every segment's control trajectories
(``c·(T_i − 2)·3``) and labels (``N``) or sparse weights. The paper thinned its 300-frame
capture to 150 frames by dropping the even-numbered frames (`thin_frames`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from fxspace._progress import progress
from fxspace._validate import check_index, check_int, checked
from fxspace.cluster import KernelKMeansResult
from fxspace.controlpoints._fitting import refine_control_points
from fxspace.controlpoints._model import (
    ControlPointModel,
    fit_control_points,
    reconstruct,
    storage_size,
)
from fxspace.controlpoints._segment import (
    Segmentation,
    check_boundaries,
    segment_motion,
    segments_from_boundaries,
)
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS

__all__ = [
    "SceneModel",
    "SceneFit",
    "SceneErrors",
    "thin_frames",
    "fit_scene",
    "reconstruct_scene",
    "linear_scene",
    "scene_errors",
    "scene_storage_size",
    "scene_compression_ratio",
    "segment_of_frame",
    "scene_to_arrays",
    "scene_from_arrays",
]


class SceneModel(NamedTuple):
    """A whole scene as per-segment control-point models.

    **Fields:** ``boundaries`` ``(s + 1,)`` frames from 0 to T−1; ``segments`` one
    `ControlPointModel` per segment (segment ``i`` spans ``boundaries[i] …
    boundaries[i+1]`` inclusive).
    """

    boundaries: Int[np.ndarray, " s1"]
    segments: tuple[ControlPointModel, ...]

    @property
    def n_frames(self) -> int:
        return int(self.boundaries[-1]) + 1

    @property
    def n_vertices(self) -> int:
        return int(self.segments[0].first.shape[0])


class SceneFit(NamedTuple):
    """Result of `fit_scene`: ``model``, the ``segmentation`` (None when boundaries
    were given), each segment's kernel k-means ``clusterings``, and each segment's
    gradient-refinement ``num_steps`` and ``refinements`` (its `fxspace.RESULTS` member;
    0 steps and ``successful`` when not refined).

    ``result``: the first segment's outcome that is not ``successful`` (clustering, then
    refinement), else ``successful``; ``converged`` (per segment, derived) and
    ``stats``."""

    model: SceneModel
    segmentation: Segmentation | None
    clusterings: tuple[KernelKMeansResult, ...]
    num_steps: tuple[int, ...]
    refinements: tuple = ()

    @property
    def converged(self) -> tuple[bool, ...]:
        """Per segment: its refinement ``successful`` (derived, not stored)."""
        return tuple(bool(r == RESULTS.successful) for r in self.refinements)

    @property
    def result(self):
        for r in (*(k.result for k in self.clusterings), *self.refinements):
            if not bool(r == RESULTS.successful):
                return r
        return RESULTS.successful

    @property
    def stats(self) -> dict:
        return {"kkm_steps": tuple(int(k.num_steps) for k in self.clusterings),
                "refine_steps": self.num_steps}  # fmt: skip


class SceneErrors(NamedTuple):
    """Eq. (1) per segment (``linear``, ``model``, ``ratio``) and for the whole scene."""

    linear: np.ndarray
    model: np.ndarray
    ratio: np.ndarray
    linear_scene: float
    model_scene: float
    ratio_scene: float


@checked
def thin_frames(X: Float[ArrayLike, "T ..."], step: int = 2) -> Float[Array, "T2 ..."]:
    """Keep every ``step``-th frame, starting at the first: with ``step = 2`` the paper's
    thinning (300 → 150 frames at 60 Hz, the even-numbered frames — counting from 1 —
    dropped)."""
    if int(step) < 1:
        raise FxspaceError(f"step must be >= 1; got {step}")
    return jnp.asarray(X)[:: int(step)]


def _check_boundaries(boundaries, T: int) -> np.ndarray:
    b = np.asarray(boundaries, dtype=np.int64)
    if b.ndim != 1 or len(b) < 2 or b[0] != 0 or b[-1] != T - 1 or np.any(np.diff(b) < 2):
        raise FxspaceError(
            f"boundaries must run from 0 to T−1 = {T - 1}, increasing by >= 2 frames (every "
            f"segment needs an in-between frame); got {b.tolist()}"
        )
    return b


@checked
def fit_scene(
    X: Float[ArrayLike, "T N 3"],
    n_clusters: int = 25,
    *,
    boundaries: Int[ArrayLike, " s1"] | None = None,
    n_segments: int | str = 8,
    min_length: int = 4,
    segment_on: str = "velocity",
    gamma: float | None = None,
    key: PRNGKeyArray | None = None,
    n_init: int = 20,
    max_points: int | None = 1000,
    refine_steps: int = 10,
    method: str = "kernel",
    segment_criterion: str = "elbow",
    fit_steps: int = 0,
    fit_support: int = 3,
    fit_smoothness: float = 1e-4,
    show_progress: bool = False,
) -> SceneFit:
    """Segment the whole sequence and model every segment by control points.

    **Arguments:**

    - `X`: ``(T, N, 3)`` the dense scene (e.g. `fxspace.rbf_deform` of a capture).
    - `n_clusters`: control points per segment (capped at the vertex count).
    - `boundaries`: given segment boundaries; ``None`` → `fxspace.segment_motion`
      with `n_segments` (a count, or ``"auto"``: chosen from the data by
      `segment_criterion`, ``"elbow"`` by default as in the reconstruction pipeline, or
      ``"bic"``), `min_length` and `segment_on`.
    - `gamma`, `n_init`, `max_points`, `refine_steps`, `method`:
      `fxspace.fit_control_points` (``method="kernel"``: kernel k-means to the end).
    - `fit_steps`: > 0 refines every segment by `fxspace.refine_control_points`
      (Adam; `fit_support`, `fit_smoothness`).
    - `key`: PRNG key (split per segment).

    **Returns:** `SceneFit`.

    **Example:**

    ```python
    fit = fx.fit_scene(X, 25, n_segments=8, key=jax.random.key(0))
    X_hat = fx.reconstruct_scene(fit.model)           # continuous at the boundaries
    err = fx.scene_errors(X, fit.model)               # err.ratio_scene, err.ratio
    ```
    """
    X = jnp.asarray(X)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 3:
        raise FxspaceError(f"X must be (frames >= 3, vertices, 3); got {X.shape}")
    T, N, _ = X.shape
    Xn = np.asarray(X)  # segments are cut on the host: no slicing program per length
    n_clusters = check_int(n_clusters, "n_clusters", low=1)
    n_init = check_int(n_init, "n_init", low=1)
    fit_steps = check_int(fit_steps, "fit_steps", low=0)
    if not isinstance(n_segments, str):
        n_segments = check_int(n_segments, "n_segments", low=1)
    seg = None
    if boundaries is None:
        seg = segment_motion(
            X, n_segments, min_length=min_length, on=segment_on,  # type: ignore[arg-type]
            criterion=segment_criterion,  # type: ignore[arg-type]
        )  # fmt: skip
        boundaries = seg.boundaries
    b = _check_boundaries(boundaries, T)
    key = jax.random.PRNGKey(0) if key is None else key
    keys = jax.random.split(key, len(b) - 1)
    models, kms, steps, conv = [], [], [], []
    spans = segments_from_boundaries(b)
    it = progress(spans, desc="control points per segment") if show_progress else spans
    for i, (a, e) in enumerate(it):
        S = jnp.asarray(Xn[a : e + 1])
        model, km = fit_control_points(
            S, min(int(n_clusters), N), gamma=gamma, key=keys[i], n_init=n_init,
            max_points=max_points, refine_steps=refine_steps, method=method,  # type: ignore[arg-type]
        )  # fmt: skip
        n_steps, ok = 0, RESULTS.successful
        if fit_steps > 0:
            fr = refine_control_points(
                S, model, steps=fit_steps, support=min(fit_support, model.controls.shape[0]),
                smoothness=fit_smoothness,
            )  # fmt: skip
            model, n_steps, ok = fr.model, int(fr.num_steps), fr.result
        models.append(model)
        kms.append(km)
        steps.append(n_steps)
        conv.append(ok)
    return SceneFit(SceneModel(b, tuple(models)), seg, tuple(kms), tuple(steps), tuple(conv))


def _stitch(parts: list[Array]) -> Array:
    return jnp.concatenate([parts[0]] + [p[1:] for p in parts[1:]], axis=0)


@checked
def reconstruct_scene(scene: SceneModel) -> Float[Array, "T N 3"]:
    """The stitched sequence: every segment's `fxspace.reconstruct`, each shared
    boundary frame once. O(T·N·c)."""
    return _stitch([reconstruct(m) for m in scene.segments])


@checked
def linear_scene(X: Float[ArrayLike, "T N 3"], boundaries: Int[ArrayLike, " s1"]) -> Array:
    """The baseline: linear interpolation between the key frames ``X[boundaries]``."""
    Xn = np.asarray(X)  # on the host: no program per segment length
    b = _check_boundaries(boundaries, Xn.shape[0])
    parts = [_linear_np(Xn[a], Xn[e], e - a + 1) for a, e in segments_from_boundaries(b)]
    return jnp.asarray(np.concatenate([parts[0]] + [p[1:] for p in parts[1:]], axis=0))


def _linear_np(first: np.ndarray, last: np.ndarray, n: int) -> np.ndarray:
    """`linear_interpolation` on the host (same formula, both key frames exact)."""
    s = np.linspace(0.0, 1.0, n).reshape((n,) + (1,) * first.ndim)
    return (1.0 - s) * first[None] + s * last[None]


@checked
def scene_errors(X: Float[ArrayLike, "T N 3"], scene: SceneModel) -> SceneErrors:
    """Eq. (1) of linear interpolation and of the model, per segment and for the scene."""
    X = jnp.asarray(X)
    if X.shape[0] != scene.n_frames or X.shape[1] != scene.n_vertices:
        raise FxspaceError(
            f"X {X.shape} does not match the scene ({scene.n_frames} frames, "
            f"{scene.n_vertices} vertices)"
        )
    Xn = np.asarray(X)  # on the host: no program per segment length
    lin, mod = [], []
    for (a, e), m in zip(segments_from_boundaries(scene.boundaries), scene.segments, strict=True):
        S = Xn[a : e + 1]
        lin.append(float(np.sum((S - _linear_np(S[0], S[-1], len(S))) ** 2)))
        mod.append(float(np.sum((S - np.asarray(reconstruct(m))) ** 2)))
    lin_a, mod_a = np.asarray(lin), np.asarray(mod)
    ratio = np.where(lin_a > 0, mod_a / np.where(lin_a > 0, lin_a, 1.0), 0.0)
    ls, ms = float(lin_a.sum()), float(mod_a.sum())
    return SceneErrors(lin_a, mod_a, ratio, ls, ms, ms / ls if ls > 0 else 0.0)


@checked
def scene_storage_size(scene: SceneModel) -> int:
    """Numbers stored for the scene: shared key frames once, plus each segment's controls
    and labels/weights (see `fxspace.storage_size`)."""
    N = scene.n_vertices
    per = sum(storage_size(m) - 2 * N * 3 for m in scene.segments)
    return (len(scene.boundaries)) * N * 3 + per


@checked
def scene_compression_ratio(scene: SceneModel) -> float:
    """Numbers in the dense scene (T·N·3) over `scene_storage_size`."""
    return scene.n_frames * scene.n_vertices * 3 / scene_storage_size(scene)


def segment_of_frame(boundaries: Int[ArrayLike, " s1"], frame: int) -> tuple[int, int]:
    """``(segment, local frame)`` of scene ``frame``: the segment whose in-between frames
    contain it; a boundary frame is a stored key frame and belongs to the segment it
    starts (the last frame to the last segment), at local frame 0 (or its end)."""
    b = check_boundaries(boundaries)
    f = check_index(frame, "frame", int(b[-1]) + 1)
    s = int(np.searchsorted(b, f, side="right") - 1)
    s = min(s, len(b) - 2)
    return s, f - int(b[s])


@checked
def scene_to_arrays(scene: SceneModel) -> dict[str, np.ndarray]:
    """Flat arrays of a scene (for ``np.savez``); inverse `scene_from_arrays`."""
    out: dict[str, np.ndarray] = {"boundaries": np.asarray(scene.boundaries, np.int64)}
    for i, m in enumerate(scene.segments):
        for f in ControlPointModel._fields:
            out[f"seg{i}_{f}"] = np.asarray(getattr(m, f))
    return out


def scene_from_arrays(arrays) -> SceneModel:
    """The `SceneModel` stored by `scene_to_arrays` (e.g. an ``np.load``)."""
    try:
        b = check_boundaries(arrays["boundaries"], "arrays['boundaries']")
        segs = tuple(
            ControlPointModel(
                *(jnp.asarray(arrays[f"seg{i}_{f}"]) for f in ControlPointModel._fields)
            )
            for i in range(len(b) - 1)
        )
    except (KeyError, IndexError, TypeError, ValueError) as e:
        if isinstance(e, FxspaceError):
            raise
        raise FxspaceError(
            f"arrays must be the mapping written by scene_to_arrays (an np.load of it); "
            f"reading it failed: {type(e).__name__}: {e}"
        ) from None
    return SceneModel(b, segs)
