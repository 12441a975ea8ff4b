"""A character driven by the capture through the control points (Hirose & Higuchi §1: the
system maps the actor's motion onto an artist's character given that character's first
and last frames of the scene).

The character is a triangle mesh with, for each capture marker, the vertex it sits on
(its marker map), and optionally the artist's first and last frames of the scene. The
capture's scene model (segments, control points) drives it:

1. **Correspondence.** The character is warped onto the capture's neutral face by the
   RBF of the marker pairs (`fxspace.rbf_deform`: its marker vertices onto the neutral
   markers), and each character vertex takes the nearest capture vertex; the similarity
   (scale ``s``, rotation ``Q``) that best aligns the neutral markers with the
   character's marker vertices (Umeyama) carries displacements across.
2. **Key frames.** At each segment boundary the character's key frame is its rest mesh
   plus ``s Q`` × its corresponding capture vertices' displacement in the scene's stored
   key frame. At the scene's first and last frames the artist's frames replace it; their
   difference is blended linearly over the scene, so every boundary gets a key frame
   consistent with both.
3. **In-betweens from the control points.** Each character vertex takes the blend
   weights of its corresponding capture vertex; inside segment
   ``i`` the character's frame ``t`` is its linear in-between of the two key frames plus
   ``s Q Σ_k w_jk R_k(t)``, the capture's control points' non-linear motion — so the
   character moves like the actor between keys, the paper's model applied to another
   face.
4. **The animator's edits.** With ``edits`` (the face-anchored keys of the editor,
   `fxspace.FaceKey`), each character vertex also takes ``s Q ×`` its corresponding
   capture vertex's edit displacement (`fxspace.edit_displacements`): the character
   carries the edits, as the paper's loop asks (the animator edits, the character
   follows).

`standin_character` makes the project's stand-in: the capture's own face surface with
different proportions (wider, shorter, deeper) and no artist frames.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float, Int

from fxspace._validate import checked
from fxspace.controlpoints._edits import FaceKey, edit_displacements
from fxspace.controlpoints._model import _control_residuals
from fxspace.controlpoints._rbf import face_surface, rbf_deform
from fxspace.controlpoints._scene import SceneModel
from fxspace.controlpoints._segment import segments_from_boundaries
from fxspace.errors import FxspaceError
from fxspace.rigid import fit_similarity, principal_axes

__all__ = ["Character", "character", "standin_character", "drive_character"]


class Character(NamedTuple):
    """A target face: ``vertices`` ``(N, 3)`` rest mesh, ``faces`` ``(F, 3)``,
    ``marker_vertex`` ``(M,)`` the vertex under each capture marker, and the artist's
    ``first``/``last`` frames of the scene ``(N, 3)`` (None: taken from the transfer)."""

    vertices: Float[np.ndarray, "N 3"]
    faces: Int[np.ndarray, "F 3"]
    marker_vertex: Int[np.ndarray, " M"]
    first: Float[np.ndarray, "N 3"] | None = None
    last: Float[np.ndarray, "N 3"] | None = None


@checked
def character(
    vertices: Float[ArrayLike, "N 3"],
    faces: Int[ArrayLike, "F 3"],
    marker_vertex: Int[ArrayLike, " M"],
    first=None,
    last=None,
) -> Character:
    """A validated `Character` (finite vertices, triangles and marker vertices in range,
    first/last of the mesh's shape)."""
    V = np.asarray(vertices, np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4 or not np.all(np.isfinite(V)):
        raise FxspaceError(f"vertices must be finite (N >= 4, 3); got shape {V.shape}")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.size and (F.min() < 0 or F.max() >= len(V)):
        raise FxspaceError(f"faces must be (F, 3) vertex indices in [0, {len(V)})")
    mv = np.asarray(marker_vertex)
    if mv.ndim != 1 or mv.dtype.kind not in "iu" or mv.min() < 0 or mv.max() >= len(V):
        raise FxspaceError(f"marker_vertex must be (M,) integer vertex indices in [0, {len(V)})")
    if len(np.unique(mv)) != len(mv):
        raise FxspaceError("marker_vertex maps two markers onto one vertex; give distinct ones")
    out = []
    for name, K in (("first", first), ("last", last)):
        if K is not None:
            K = np.asarray(K, np.float64)
            if K.shape != V.shape or not np.all(np.isfinite(K)):
                raise FxspaceError(f"{name} must be finite with the mesh's shape {V.shape}")
        out.append(K)
    return Character(V, F.astype(np.int32), mv.astype(np.int64), out[0], out[1])


@checked
def standin_character(
    neutral_markers: Float[ArrayLike, "M 3"],
    n_vertices: int = 3000,
    proportions: tuple[float, float, float] = (1.2, 0.85, 1.3),
) -> Character:
    """The project's stand-in character: the capture's face surface (`face_surface`)
    stretched by ``proportions`` along its width, height and depth axes (principal axes
    of the neutral markers) — another face, same marker layout."""
    m = np.asarray(neutral_markers, np.float64)
    surf = face_surface(m, n_vertices)
    mu, vt = principal_axes(m)
    V = mu + ((surf.vertices - mu) @ vt.T * np.asarray(proportions, np.float64)) @ vt
    return character(V, surf.faces, surf.marker_vertex)


def _nearest(P: np.ndarray, Q: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Index of the nearest row of ``Q`` for each row of ``P``."""
    q2 = np.sum(Q * Q, 1)
    out = np.empty(len(P), np.int64)
    for a in range(0, len(P), chunk):
        B = P[a : a + chunk]
        out[a : a + chunk] = np.argmin(q2[None, :] - 2.0 * B @ Q.T, axis=1)
    return out


@checked
def drive_character(
    char: Character,
    scene: SceneModel,
    markers: Float[ArrayLike, "T M 3"],
    source_rest: Float[ArrayLike, "Ns 3"],
    edits: tuple[FaceKey, ...] | list[FaceKey] = (),
) -> Float[np.ndarray, "T N 3"]:
    """The character's frames driven by the capture (module docstring).

    **Arguments:** `char` the target; `scene` the capture's fitted scene model
    (`fxspace.fit_scene`); `markers` ``(T, M, 3)`` the capture's markers (complete), in
    the scene's frames; `source_rest` ``(Ns, 3)`` the capture's dense face at frame 0;
    `edits`: the animator's face-anchored keys (`fxspace.FaceKey`, as the editor saves
    them), carried onto the character (step 4).

    **Returns:** ``(T, N, 3)``, equal to the artist's first and last frames at the ends.
    """
    M = np.asarray(markers, np.float64)
    T = scene.n_frames
    if M.ndim != 3 or M.shape[0] != T or M.shape[2] != 3 or not np.all(np.isfinite(M)):
        raise FxspaceError(
            f"markers must be finite ({T}, M, 3) (the scene's frames); got {M.shape}"
        )
    if M.shape[1] != len(char.marker_vertex):
        raise FxspaceError(
            f"the character maps {len(char.marker_vertex)} markers; the capture has {M.shape[1]}"
        )
    S0 = np.asarray(source_rest, np.float64)
    if S0.shape != (scene.n_vertices, 3):
        raise FxspaceError(f"source_rest must be ({scene.n_vertices}, 3); got {S0.shape}")
    Pt = char.vertices[char.marker_vertex]
    Q, s, _ = fit_similarity(M[0], Pt)
    # correspondence: the character warped onto the capture's neutral face, nearest vertex
    warp = np.asarray(
        rbf_deform(jnp.asarray(char.vertices), jnp.asarray(Pt), jnp.asarray(M[0][None]))
    )[0]
    nn = _nearest(warp, S0)
    b = np.asarray(scene.boundaries)
    stored = [m.first for m in scene.segments] + [scene.segments[-1].last]
    keys = {int(f): char.vertices + s * (np.asarray(K, np.float64)[nn] - S0[nn]) @ Q.T
            for f, K in zip(b, stored, strict=True)}  # fmt: skip
    d0 = 0.0 if char.first is None else char.first - keys[0]
    d1 = 0.0 if char.last is None else char.last - keys[T - 1]
    for f in keys:  # the artist's frames, blended linearly over the scene
        keys[f] = keys[f] + (1.0 - f / (T - 1)) * d0 + (f / (T - 1)) * d1
    out = np.empty((T, len(char.vertices), 3))
    for (a, e), m in zip(segments_from_boundaries(scene.boundaries), scene.segments, strict=True):
        n = e - a + 1
        u = np.linspace(0.0, 1.0, n)[:, None, None]
        L = (1.0 - u) * keys[a][None] + u * keys[e][None]
        R = np.asarray(_control_residuals(m.controls), np.float64)  # (c, n, 3)
        W = np.asarray(m.weights, np.float64)[nn]  # (N, c)
        out[a : e + 1] = L + s * np.einsum("nk,ktd->tnd", W, R) @ Q.T
    if len(edits):
        D = edit_displacements(scene, list(edits))  # (T, Ns, 3), the capture's units
        out += s * D[:, nn] @ Q.T
    return out
