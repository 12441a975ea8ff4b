"""Markers on the visible triangles of a mesh (Park, Kang & Kwon, §3.1).

A triangle ``(a, b, c)`` (counter-clockwise = front, as in glTF) faces a camera looking
along ``view_dir`` when its normal ``n = (b − a) × (c − a)`` satisfies ``n · view_dir < 0``
(back-face test; no occlusion test). Markers are placed one per triangle at most, at
random (uniform on the triangle) or chosen barycentric coordinates, as in the paper.

A marker's position is the barycentric blend of its triangle's posed vertices, and as
LBS is linear, it is itself a skinned point: ``p_k = Σ_j (W_kj · o_j + L_j u_kj)`` with
per-(marker, joint) weights ``W_kj = Σ_m b_m w_{i_m j}`` and bind-local offsets
``u_kj = B_j⁻¹ Σ_m b_m w_{i_m j} v_{i_m}`` (`marker_influences`) — exact, not an
approximation by the nearest vertex.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from fxspace._validate import _is_tracer, as_float_array, check_indices, check_int, checked
from fxspace.errors import FxspaceError

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import SkinnedMesh

__all__ = [
    "MarkerSet",
    "MarkerInfluences",
    "triangle_normals",
    "visible_triangles",
    "place_markers",
    "marker_positions",
    "marker_influences",
]


class MarkerSet(NamedTuple):
    """Markers: the triangle each lies on and its barycentric coordinates."""

    triangles: Int[Array, " markers"]
    barycentric: Float[Array, "markers 3"]


class MarkerInfluences(NamedTuple):
    """Sparse skinning of markers: ``N`` (joint, weight, bind-local offset) entries per marker."""

    joints: np.ndarray  # (K, N) int32 (padding: joint 0, weight 0)
    weights: np.ndarray  # (K, N)   W_kj
    offsets: np.ndarray  # (K, N, 3) u_kj = B_j⁻¹-mapped, weight-scaled positions


def _check_faces(faces, n_verts: int):
    """``faces`` as an ``(F, 3)`` int array of vertex indices in range (traced: shape only)."""
    if not _is_tracer(faces):
        if isinstance(faces, str | bytes) or faces is None:
            raise FxspaceError(f"faces must be an (F, 3) integer array, got {faces!r}")
        check_indices(np.ravel(faces), "faces", n_verts, min_len=1)
    f = jnp.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise FxspaceError(f"faces must be an (F, 3) integer array, got shape {f.shape}")
    return f


def triangle_normals(
    vertices: Float[Array, "verts 3"], faces: Int[Array, "faces 3"]
) -> Float[Array, "faces 3"]:
    """Unnormalised triangle normals ``(b − a) × (c − a)``."""
    v = as_float_array(vertices, "vertices", shape=(None, 3), finite="allow")
    f = _check_faces(faces, v.shape[0])
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return jnp.cross(b - a, c - a)


def visible_triangles(
    vertices: Float[Array, "verts 3"],
    faces: Int[Array, "faces 3"],
    view_dir: Float[Array, " 3"],
) -> Bool[Array, " faces"]:
    """Triangles facing a camera looking along ``view_dir``: ``n · view_dir < 0``.

    Degenerate (zero-area) triangles are never visible.
    """
    n = triangle_normals(vertices, faces)
    view_dir = as_float_array(view_dir, "view_dir", shape=(3,)).astype(n.dtype)
    return jnp.einsum("fc,c->f", n, view_dir) < 0


def place_markers(
    vertices: Float[Array, "verts 3"],
    faces: Int[Array, "faces 3"],
    num_markers: int,
    view_dir=(0.0, 0.0, -1.0),
    *,
    seed: int | np.random.Generator = 0,
    barycentric: Float[Array, "markers 3"] | None = None,
    triangles: Int[Array, " markers"] | None = None,
) -> MarkerSet:
    """Place ``num_markers`` markers on distinct visible triangles.

    **Arguments:**

    - `vertices`, `faces`: the mesh (usually the bind pose).
    - `num_markers`: how many markers (at most the number of visible triangles).
    - `view_dir`: the camera's viewing direction (default ``-z``: a camera on ``+z``).
    - `seed`: a seed or ``numpy.random.Generator`` choosing the triangles (without
      replacement, uniformly among the visible ones) and the barycentric points
      (uniform on each triangle).
    - `barycentric`: optional ``(K, 3)`` barycentric coordinates (rows summing to 1).
    - `triangles`: optional ``(K,)`` triangle indices (distinct, visible), instead of random.

    **Returns:** a `MarkerSet`. Runs on the host (numpy), at set-up time.
    """
    v = np.asarray(as_float_array(vertices, "vertices"), dtype=np.float64)  # NaN: blamed here
    f = np.asarray(faces)
    num_markers = check_int(num_markers, "num_markers", low=1)
    if not isinstance(seed, np.random.Generator):
        seed = check_int(seed, "seed", low=0)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise FxspaceError(f"vertices must be (V, 3) and faces (F, 3); got {v.shape}, {f.shape}")
    d = np.asarray(view_dir, dtype=np.float64)
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise FxspaceError(f"view_dir must be a non-zero 3-vector, got {view_dir!r}")
    vis = np.flatnonzero(np.asarray(visible_triangles(v, f, d)))
    k = int(num_markers)
    if k < 1:
        raise FxspaceError(f"num_markers must be >= 1, got {num_markers}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if triangles is not None:
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1)
        if tri.shape[0] != k or len(np.unique(tri)) != k:
            raise FxspaceError(f"triangles must be {k} distinct triangle indices")
        if not np.isin(tri, vis).all():
            raise FxspaceError(f"triangles {tri[~np.isin(tri, vis)].tolist()} do not face view_dir")
    else:
        if k > vis.size:
            raise FxspaceError(
                f"num_markers={k} exceeds the {vis.size} triangles facing view_dir={d.tolist()} "
                "(one marker per triangle at most); lower num_markers"
            )
        tri = rng.choice(vis, size=k, replace=False)
    if barycentric is None:
        r1, r2 = rng.random(k), rng.random(k)
        s = np.sqrt(r1)
        bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    else:
        bary = np.asarray(barycentric, dtype=np.float64)
        if bary.shape != (k, 3) or np.any(bary < -1e-12) or not np.allclose(bary.sum(1), 1.0):
            raise FxspaceError(f"barycentric must be ({k}, 3), non-negative, rows summing to 1")
    return MarkerSet(jnp.asarray(tri.astype(np.int32)), jnp.asarray(bary))


@checked
def marker_positions(
    vertices: Float[Array, "*b verts 3"], faces: Int[Array, "faces 3"], markers: MarkerSet
) -> Float[Array, "*b markers 3"]:
    """Marker positions on (posed) vertices: barycentric blends of their triangles' corners."""
    f = jnp.asarray(faces)[markers.triangles]  # (K, 3)
    corners = jnp.asarray(vertices)[..., f, :]  # (*b, K, 3, 3)
    return jnp.einsum("...kmc,km->...kc", corners, markers.barycentric)


@checked
def marker_influences(mesh: SkinnedMesh, markers: MarkerSet) -> MarkerInfluences:
    """Per-marker joint weights ``W_kj`` and bind-local offsets ``u_kj`` (see module docstring).

    Only joints with ``W_kj > 0`` are kept; ``N`` is the largest count over the markers
    (at most 3 × influences per vertex).
    """
    faces = np.asarray(mesh.faces)
    tri = np.asarray(markers.triangles)
    bary = np.asarray(markers.barycentric, dtype=np.float64)
    corner = faces[tri]  # (K, 3)
    nk, nj = tri.shape[0], mesh.num_joints
    wd = np.zeros((nk, nj))
    ud = np.zeros((nk, nj, 3))
    for m in range(3):
        vi = corner[:, m]
        jj = mesh.skin_joints[vi]  # (K, I)
        ww = mesh.skin_weights[vi] * bary[:, m : m + 1]  # (K, I)
        rows = np.repeat(np.arange(nk), jj.shape[1])
        np.add.at(wd, (rows, jj.reshape(-1)), ww.reshape(-1))
        np.add.at(
            ud,
            (rows, jj.reshape(-1)),
            (ww[:, :, None] * mesh.vertices[vi][:, None, :]).reshape(-1, 3),
        )
    ibm = np.asarray(mesh.inverse_bind, dtype=np.float64)
    # u' = B⁻¹_lin u + W B⁻¹_t
    up = np.einsum("jrc,kjc->kjr", ibm[:, :3, :3], ud) + wd[:, :, None] * ibm[None, :, :3, 3]
    nz = wd > 0
    n = max(int(nz.sum(axis=1).max()), 1)
    joints = np.zeros((nk, n), dtype=np.int32)
    weights = np.zeros((nk, n))
    offsets = np.zeros((nk, n, 3))
    for k in range(nk):
        idx = np.flatnonzero(nz[k])
        joints[k, : idx.size] = idx
        weights[k, : idx.size] = wd[k, idx]
        offsets[k, : idx.size] = up[k, idx]
    return MarkerInfluences(joints, weights, offsets)
