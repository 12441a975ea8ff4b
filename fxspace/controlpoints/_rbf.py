"""Marker → dense mesh transfer by radial-basis-function (RBF) deformation.

The standard way motion capture drives a face mesh: the displacement of every mesh
vertex is the RBF interpolant of the markers' displacements,

    u(p) = Σ_j w_j φ(‖p − m_j‖) + A p + b,   u(m_j) = m_j(t) − m_j(0),

with the polyharmonic kernel ``φ(r) = r`` (the 3-D biharmonic spline, Carr et al. 2001)
and an affine part, so rigid and affine marker motion (e.g. head motion) transfer exactly.
The rest markers are fixed, so the interpolation system is solved once: the transfer is a
fixed linear map ``A ∈ R^{N×M}`` from marker displacements to vertex displacements and a
whole sequence costs one ``(N × M)·(M × 3T)`` product.

`face_surface` builds a dense face surface from the neutral markers alone (a grid
on the markers' principal plane inside their dilated convex hull, depth from a 2-D
thin-plate spline through the markers); a user mesh with its own rest vertices can be
driven the same way with `rbf_deform`.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.rigid import principal_axes

__all__ = ["rbf_transfer_matrix", "rbf_deform", "face_surface", "FaceSurface"]


def _phi(r: Array, kernel: str) -> Array:
    if kernel == "biharmonic":  # 3-D: φ = r
        return r
    if kernel == "triharmonic":  # 3-D: φ = r³
        return r**3
    if kernel == "thin_plate":  # 2-D: φ = r² log r
        return jnp.where(r > 0, r * r * jnp.log(jnp.where(r > 0, r, 1.0)), 0.0)
    raise FxspaceError(
        f"kernel must be 'biharmonic', 'triharmonic' or 'thin_plate'; got {kernel!r}"
    )


def _dist(a: Array, b: Array) -> Array:
    d2 = jnp.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1)
    return jnp.sqrt(jnp.maximum(d2, 0.0))


def _check_distinct(S, name: str) -> None:
    """Refuse coinciding source points (the interpolation system would be singular and
    every vertex NaN); skipped under jit."""
    if isinstance(S, jax.core.Tracer):
        return
    P = np.asarray(S, np.float64)
    if not np.all(np.isfinite(P)):
        raise FxspaceError(f"{name} contain NaN/inf; use a frame where every marker is seen")
    scale = max(float(np.ptp(P, axis=0).max()) if len(P) else 0.0, 1e-300)
    d = np.sqrt(np.maximum(np.sum((P[:, None] - P[None]) ** 2, -1), 0.0))
    d[np.diag_indices(len(P))] = np.inf
    i, j = np.unravel_index(int(np.argmin(d)), d.shape) if len(P) > 1 else (0, 0)
    if len(P) > 1 and d[i, j] <= 1e-9 * scale:
        raise FxspaceError(
            f"{name} {min(i, j)} and {max(i, j)} are at the same place; drop or merge "
            "duplicate markers (the RBF system is singular otherwise)"
        )


@checked
def rbf_transfer_matrix(
    targets: Float[ArrayLike, "N D"],
    sources: Float[ArrayLike, "M D"],
    kernel: Literal["biharmonic", "triharmonic", "thin_plate"] = "biharmonic",
    smoothing: float = 0.0,
) -> Float[Array, "N M"]:
    """Linear map ``A`` with ``f(targets) ≈ A f(sources)`` for the RBF interpolant of ``f``.

    The interpolant has kernel ``φ`` plus an affine polynomial (reproduced exactly);
    ``smoothing`` > 0 adds ``smoothing·I`` to the kernel block (regularised fit). Solves
    one ``(M + D + 1)``-square system: O(M³ + N·M) time, O(N·M) memory.
    """
    X = jnp.asarray(targets)
    S = jnp.asarray(sources)
    if X.ndim != 2 or S.ndim != 2 or X.shape[1] != S.shape[1]:
        raise FxspaceError(
            f"targets {X.shape} and sources {S.shape} must be (N, D) and (M, D) with the same D"
        )
    M, D = S.shape
    _check_distinct(S, "sources")
    if M < D + 1:
        raise FxspaceError(
            f"need at least D+1 = {D + 1} source points for the affine part; got {M}"
        )
    Phi = _phi(_dist(S, S), kernel) + smoothing * jnp.eye(M, dtype=S.dtype)
    P = jnp.concatenate([S, jnp.ones((M, 1), S.dtype)], axis=1)
    top = jnp.concatenate([Phi, P], axis=1)
    bot = jnp.concatenate([P.T, jnp.zeros((D + 1, D + 1), S.dtype)], axis=1)
    L = jnp.concatenate([top, bot], axis=0)
    rhs = jnp.concatenate([jnp.eye(M, dtype=S.dtype), jnp.zeros((D + 1, M), S.dtype)], axis=0)
    coef = jnp.linalg.solve(L, rhs)  # (M + D + 1, M): weights and affine part per unit datum
    E = jnp.concatenate([_phi(_dist(X, S), kernel), X, jnp.ones((X.shape[0], 1), X.dtype)], axis=1)
    return E @ coef


@checked
def rbf_deform(
    rest_vertices: Float[ArrayLike, "N 3"],
    rest_markers: Float[ArrayLike, "M 3"],
    markers: Float[ArrayLike, "T M 3"],
    kernel: Literal["biharmonic", "triharmonic"] = "biharmonic",
    smoothing: float = 0.0,
) -> Float[Array, "T N 3"]:
    """Vertex trajectories ``v(t) = v(0) + A (m(t) − m(0))`` driven by marker trajectories.

    ``markers`` must be complete (no NaN): fill gaps before the transfer.
    """
    m = jnp.asarray(markers)
    if m.ndim != 3 or m.shape[2] != 3:
        raise FxspaceError(f"markers must be (frames, markers, 3); got {m.shape}")
    try:
        finite = bool(np.all(np.isfinite(np.asarray(m))))
    except Exception:  # under jit: kernels assume
        finite = True
    if not finite:
        raise FxspaceError("markers contain NaN/inf; fill missing markers before rbf_deform")
    A = rbf_transfer_matrix(rest_vertices, rest_markers, kernel, smoothing)
    disp = m - jnp.asarray(rest_markers)[None]
    return jnp.asarray(rest_vertices)[None] + jnp.einsum("nm,tmd->tnd", A, disp)


class FaceSurface(NamedTuple):
    """A dense face surface built from neutral markers.

    **Fields:** ``vertices (N, 3)``, ``faces (F, 3)`` triangles, ``marker_vertex (M,)`` the
    vertex nearest to each marker, ``uv (N, 2)`` coordinates on the face's principal plane.
    """

    vertices: Float[np.ndarray, "N 3"]
    faces: Int[np.ndarray, "F 3"]
    marker_vertex: Int[np.ndarray, " M"]
    uv: Float[np.ndarray, "N 2"]


def _convex_hull(p: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (Andrew's monotone chain) of 2-D points."""
    pts = sorted(map(tuple, p))

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for q in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    upper: list = []
    for q in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def _inside_dilated(hull: np.ndarray, q: np.ndarray, margin: float) -> np.ndarray:
    """Points ``q`` within ``margin`` outside the convex polygon ``hull`` (CCW)."""
    a = hull
    b = np.roll(hull, -1, axis=0)
    e = b - a
    nrm = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)
    signed = np.einsum("qkd,kd->qk", q[:, None, :] - a[None], nrm)  # > 0 outside edge k
    return np.all(signed <= margin, axis=1)


@checked
def face_surface(
    neutral_markers: Float[ArrayLike, "M 3"],
    n_vertices: int = 6000,
    margin: float = 0.08,
) -> FaceSurface:
    """Dense triangulated face surface from neutral markers (no mesh needed).

    The markers' principal plane (PCA) carries a regular grid clipped to their convex
    hull dilated by ``margin`` × the face width; each grid point's depth (third principal
    axis) is the 2-D thin-plate-spline interpolant of the markers' depths. The grid
    spacing is chosen so that about ``n_vertices`` points fall inside.
    """
    m = np.asarray(neutral_markers, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3 or m.shape[0] < 4:
        raise FxspaceError(f"neutral_markers must be (M >= 4, 3); got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise FxspaceError("neutral_markers contain NaN; use a frame where every marker is seen")
    if n_vertices < 16:
        raise FxspaceError(f"n_vertices must be >= 16; got {n_vertices}")
    mu, vt = principal_axes(m)
    uvw = (m - mu) @ vt.T
    uv_m, w_m = uvw[:, :2], uvw[:, 2]
    hull = _convex_hull(uv_m)
    width = float(np.ptp(uv_m, axis=0).max())
    pad = margin * width
    lo, hi = uv_m.min(0) - pad, uv_m.max(0) + pad
    # hull area (shoelace) of the dilated hull, approximately, sets the spacing
    x, y = hull[:, 0], hull[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    perim = np.sum(np.linalg.norm(hull - np.roll(hull, -1, axis=0), axis=1))
    area += perim * pad + np.pi * pad**2
    h = np.sqrt(area / n_vertices)
    gx = np.arange(lo[0], hi[0] + h, h)
    gy = np.arange(lo[1], hi[1] + h, h)
    G = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1)  # (nx, ny, 2)
    nx, ny = G.shape[:2]
    inside = _inside_dilated(hull, G.reshape(-1, 2), pad).reshape(nx, ny)
    index = -np.ones((nx, ny), np.int64)
    index[inside] = np.arange(int(inside.sum()))
    uv = G[inside]
    A = np.asarray(rbf_transfer_matrix(jnp.asarray(uv), jnp.asarray(uv_m), "thin_plate"))
    w = A @ w_m
    verts = mu + np.concatenate([uv, w[:, None]], axis=1) @ vt
    # triangles: split each grid cell along its diagonal, keep those with all corners inside
    i00 = index[:-1, :-1]
    i10 = index[1:, :-1]
    i01 = index[:-1, 1:]
    i11 = index[1:, 1:]
    t1 = np.stack([i00, i10, i11], -1).reshape(-1, 3)
    t2 = np.stack([i00, i11, i01], -1).reshape(-1, 3)
    tris = np.concatenate([t1, t2], 0)
    tris = tris[np.all(tris >= 0, axis=1)].astype(np.int32)
    d = np.linalg.norm(verts[None, :, :] - m[:, None, :], axis=-1)
    return FaceSurface(verts, tris, np.argmin(d, axis=1).astype(np.int32), uv)
