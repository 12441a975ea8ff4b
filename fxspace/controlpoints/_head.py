"""A recognisable head driven only by captured face markers (for the studio apps).

`head_model` fits a smooth, closed template head to one neutral frame of markers: an
ellipsoidal skull sized by the markers, whose front is moved onto the markers by a 2-D
thin-plate spline of their depths; a mouth slit cut along the line between the mouth
corners (the upper and lower lip edges are separate vertices), eyeballs at the eyes, a dark
mouth interior behind the lips. `head_vertices` then drives every vertex by the markers
through the RBF transfer (biharmonic kernel + affine part, as `rbf_transfer_matrix`):
``v(t) = v(0) + A (m(t) − m(0))``, one ``(N × M)·(M × 3)`` product per frame. The transfer
of the vertices below the mouth line ignores the upper-lip markers and that of the
vertices above ignores the lower-lip, chin and jaw markers (blended smoothly beyond the
mouth corners), so the lips part when the jaw markers open.

Marker names (AnimFace's ``Mouth_Up``/``Leye_Up``…, the synthetic face's
``lip_upper_c``/``eye_l_upper``…) locate the mouth and the eyes; without names, the
usual proportions of a face are used.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.rigid import principal_axes

__all__ = ["HeadModel", "head_model", "head_vertices", "HEAD_COLOURS"]

HEAD_COLOURS = {
    "skin": (228, 188, 164),
    "lips": (178, 92, 92),
    "brows": (120, 86, 64),
    "eyes": (246, 246, 242),
    "irises": (52, 40, 30),
    "mouth": (70, 22, 26),
}
"""The colour of each part of the head (RGB)."""


class HeadModel(NamedTuple):
    """A template head fitted to neutral markers (a pytree of arrays).

    - `rest`: ``(N, 3)`` vertices at the neutral frame (capture coordinates).
    - `faces`: ``(F, 3)`` triangles, outward, one closed skin surface plus the eyeballs and
      the mouth interior.
    - `part`: ``(F,)`` index into `parts` of each triangle.
    - `parts`: the part names (keys of `HEAD_COLOURS`).
    - `transfer`: ``(N, M)`` RBF transfer from marker displacements to vertices.
    - `rest_markers`: ``(M, 3)`` the neutral markers.
    - `lower`: ``(N,)`` in [0, 1], how much each vertex follows the lower jaw.
    - `axes`: ``(3, 3)`` rows: the face's right, up and out (toward a viewer) directions.
    - `colors`: ``(N, 3)`` uint8 per-vertex colours (skin, lips, brows, eyes blend
      smoothly: no stair-stepped colour edges).
    """

    rest: np.ndarray
    faces: np.ndarray
    part: np.ndarray
    parts: tuple[str, ...]
    transfer: np.ndarray
    rest_markers: np.ndarray
    lower: np.ndarray
    axes: np.ndarray
    colors: np.ndarray


def _rbf(targets: np.ndarray, sources: np.ndarray, kernel: str = "biharmonic",
         smoothing: float = 0.0) -> np.ndarray:  # fmt: skip
    """``(N, M)`` RBF transfer (kernel + affine part), as `rbf_transfer_matrix`, in NumPy
    float64 (a one-off fit: no compilation)."""

    def phi(r):
        if kernel == "biharmonic":
            return r
        return np.where(r > 0, r * r * np.log(np.where(r > 0, r, 1.0)), 0.0)

    def dist(a, b):
        return np.sqrt(np.maximum(np.sum((a[:, None, :] - b[None, :, :]) ** 2, -1), 0.0))

    S, X = np.asarray(sources, np.float64), np.asarray(targets, np.float64)
    M, D = S.shape
    P = np.concatenate([S, np.ones((M, 1))], 1)
    L = np.block([[phi(dist(S, S)) + smoothing * np.eye(M), P], [P.T, np.zeros((D + 1, D + 1))]])
    coef = np.linalg.solve(L, np.concatenate([np.eye(M), np.zeros((D + 1, M))]))
    return np.concatenate([phi(dist(X, S)), X, np.ones((len(X), 1))], 1) @ coef


def _frame(m: np.ndarray, names) -> np.ndarray:
    """(3, 3) rows right, up, out of the face (PCA; with names, up from chin to forehead)."""
    mu, vt = principal_axes(m)
    q = m - mu
    right, up = vt[0], vt[1]
    low = [n.lower() for n in names] if names is not None else []
    top = [i for i, n in enumerate(low) if "forehead" in n]
    bot = [i for i, n in enumerate(low) if n.startswith("chin")]
    if top and bot:
        d = m[top].mean(0) - m[bot].mean(0)
        if abs(d @ vt[0]) > abs(d @ vt[1]):
            right, up = vt[1], vt[0]
        up = up if d @ up > 0 else -up
    out = np.cross(right, up)
    # the face bulges toward the viewer: the nose is in front of the markers' plane
    nose = [i for i, n in enumerate(low) if "nose" in n and ("head" in n or "tip" in n)]
    if nose and (q[nose].mean(0) @ out) < 0:
        right, out = -right, -out
    return np.stack([right, up, out])


class _Landmarks(NamedTuple):
    mouth_v: float
    corners: tuple[float, float]  # u of the two mouth corners (left < right)
    lip_h: float
    eyes: np.ndarray  # (2, 3) eye centres (u, v, w)
    eye_r: float
    upper: np.ndarray  # marker indices of the upper lip
    lower: np.ndarray  # marker indices of the lower lip, chin and jaw
    brows: np.ndarray  # marker indices of the eyebrows


def _find(low, *keys, exclude=()) -> list[int]:
    return [
        i for i, n in enumerate(low)
        if any(k in n for k in keys) and not any(x in n for x in exclude)
    ]  # fmt: skip


def _landmarks(q: np.ndarray, names) -> _Landmarks:
    """Mouth line, corners, eyes and the lip / jaw marker groups, by name or proportion."""
    low = [n.lower() for n in names] if names is not None else [""] * len(q)
    lo, hi = q.min(0), q.max(0)
    W, H = hi[0] - lo[0], hi[1] - lo[1]
    corners = _find(low, "lend", "rend", "corner")
    up = _find(low, "mouth_up", "lip_upper", "upperlip")
    dn = _find(low, "mouth_down", "lip_lower", "lowerlip", "chin", "jaw")
    if len(corners) >= 2:
        cu = np.sort(q[corners, 0])
        mouth_v = float(q[corners, 1].mean())
        c = (float(cu[0]), float(cu[-1]))
    else:
        mouth_v, c = lo[1] + 0.25 * H, (-0.2 * W, 0.2 * W)
    if not up or not dn:  # by position: around the mouth, above / below its line
        near = np.abs(q[:, 0] - 0.5 * (c[0] + c[1])) < 0.7 * (c[1] - c[0])
        up = list(np.flatnonzero(near & (q[:, 1] > mouth_v) & (q[:, 1] < mouth_v + 0.12 * H)))
        dn = list(np.flatnonzero(q[:, 1] < mouth_v - 0.02 * H))
    lips = [i for i in dn if q[i, 1] > mouth_v - 0.1 * H]
    gap = np.median(q[up, 1]) - np.median(q[lips, 1]) if up and lips else 0.1 * H
    lip_h = 0.5 * float(np.clip(gap, 0.03 * H, 0.12 * H))
    eyes, eye_r = [], 0.06 * W
    for side in (("leye", "eye_l"), ("reye", "eye_r")):
        idx = _find(low, *side, exclude=("brow",))
        if idx:
            eyes.append(q[idx].mean(0))
            eye_r = 0.5 * float(np.ptp(q[idx, 0])) * 0.55 if len(idx) > 1 else eye_r
    if len(eyes) < 2:
        eyes = [np.array([s * 0.22 * W, lo[1] + 0.66 * H, 0.0]) for s in (-1, 1)]
    brows = _find(low, "brow")
    return _Landmarks(
        mouth_v,
        c,
        lip_h,
        np.asarray(eyes, float),
        max(eye_r, 0.03 * W),
        np.asarray(up, int),
        np.asarray(dn, int),
        np.asarray(brows, int),
    )


def _snap(grid: np.ndarray, value: float) -> tuple[np.ndarray, int]:
    k = int(np.argmin(np.abs(grid - value)))
    g = grid.copy()
    g[k] = value
    return g, k


def _skin_grid(q, lm: _Landmarks, n_rows: int, n_cols: int):
    """Ellipsoid (θ rows, φ columns; φ = 0 faces the viewer) whose row k_m runs through the
    mouth line and whose columns j_l, j_r pass through the mouth corners."""
    lo, hi = q.min(0), q.max(0)
    a = 0.5 * (hi[0] - lo[0]) * 1.2
    H = hi[1] - lo[1]
    v0, b = lo[1] + 0.6 * H, 0.74 * H
    depth = 1.15 * a
    w0 = float(np.median(q[:, 2])) - depth * 0.92
    th = np.linspace(0.0, np.pi, n_rows)
    th, km = _snap(th, float(np.arccos(np.clip((lm.mouth_v - v0) / b, -0.99, 0.99))))
    ph = np.linspace(-np.pi, np.pi, n_cols, endpoint=False)
    s = a * np.sin(th[km])
    ph, jl = _snap(ph, float(np.arcsin(np.clip(lm.corners[0] / s, -0.95, 0.95))))
    ph, jr = _snap(ph, float(np.arcsin(np.clip(lm.corners[1] / s, -0.95, 0.95))))
    T, P = np.meshgrid(th, ph, indexing="ij")
    taper = 1.0 - 0.22 * np.clip(-np.cos(T), 0, 1) ** 1.5  # narrower jaw
    U = a * np.sin(T) * np.sin(P) * taper
    V = v0 + b * np.cos(T)
    Wd = w0 + depth * np.sin(T) * np.cos(P) * taper
    return np.stack([U, V, Wd], -1), km, (jl, jr), (a, b, v0, depth, w0)


def _fit_front(G: np.ndarray, q: np.ndarray, dims) -> np.ndarray:
    """Move the front of the grid onto the markers: a 2-D thin-plate spline of the markers'
    depth offsets from the template, faded out beyond the markers and on the sides."""
    a, b, v0, depth, w0 = dims
    uv = q[:, :2]
    front = w0 + depth * np.sqrt(np.clip(1 - (uv[:, 0] / a) ** 2 - ((uv[:, 1] - v0) / b) ** 2,
                                         0, 1))  # fmt: skip
    off = q[:, 2] - front
    pts = G.reshape(-1, 3)
    A = _rbf(pts[:, :2], uv, "thin_plate", smoothing=1e-3)
    d = A @ off
    c, half = 0.5 * (uv.max(0) + uv.min(0)), 0.5 * np.ptp(uv, 0) * 1.1
    r = np.sqrt(np.sum(((pts[:, :2] - c) / half) ** 2, axis=1))
    fade = np.exp(-8.0 * np.clip(r - 1.0, 0, None) ** 2)
    facing = np.clip((pts[:, 2] - w0) / depth, 0, 1) ** 1.5
    out = pts.copy()
    out[:, 2] += d * fade * facing
    return out


def _grid_faces(n_rows: int, n_cols: int, km: int, jl: int, jr: int, dup: dict[int, int]):
    """Triangles of the (rows × cols) grid, wrapped in φ, with fans at the poles collapsed;
    below the mouth row the slit's vertices are replaced by their duplicates."""
    idx = np.arange(n_rows * n_cols).reshape(n_rows, n_cols)
    tris = []
    for i in range(n_rows - 1):
        for j in range(n_cols):
            j2 = (j + 1) % n_cols
            a, b, c, d = idx[i, j], idx[i, j2], idx[i + 1, j], idx[i + 1, j2]
            if i == km:  # the quad below the mouth row uses the lower lip's copies
                a, b = dup.get(int(a), int(a)), dup.get(int(b), int(b))
            if i > 0:
                tris.append((a, c, b))
            if i + 1 < n_rows - 1:
                tris.append((b, c, d))
    return np.asarray(tris, np.int64)


def _sphere(centre: np.ndarray, r: float, n: int = 14):
    th = np.linspace(0, np.pi, n)
    ph = np.linspace(-np.pi, np.pi, 2 * n, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(T) * np.sin(P), np.cos(T), np.sin(T) * np.cos(P)], -1).reshape(-1, 3)
    return centre + r * V, _grid_faces(n, 2 * n, -1, 0, 0, {}), V[:, 2]


@checked
def head_model(
    rest_markers: Float[ArrayLike, "M 3"],
    names: Sequence[str] | None = None,
    resolution: int = 72,
) -> HeadModel:
    """Fit the template head to neutral markers ``(M, 3)`` (see the module docstring).

    **Arguments:** `rest_markers` (M ≥ 6, finite, distinct), optional marker `names`,
    `resolution` (rows of the skin grid, ≥ 24; columns 1.5×; N ≈ 1.5·resolution²).

    **Returns:** a `HeadModel`; `head_vertices` poses it for a frame of markers.
    """
    m = np.asarray(rest_markers, np.float64)
    if m.ndim != 2 or m.shape[1] != 3 or len(m) < 6 or not np.all(np.isfinite(m)):
        raise FxspaceError(f"rest_markers must be finite (M >= 6, 3); got shape {m.shape}")
    if names is not None and len(names) != len(m):
        raise FxspaceError(f"names has {len(names)} entries for {len(m)} markers")
    if int(resolution) < 24:
        raise FxspaceError(f"resolution must be >= 24, got {resolution}")
    R = _frame(m, names)
    c = m.mean(0)
    q = (m - c) @ R.T
    lm = _landmarks(q, names)
    nr, nc = int(resolution), int(1.5 * int(resolution))
    G, km, (jl, jr), dims = _skin_grid(q, lm, nr, nc)
    skin = _fit_front(G, q, dims)
    return _assemble(m, q, R, c, lm, skin, (nr, nc, km, jl, jr), dims)


def _assemble(m, q, R, c, lm: _Landmarks, skin, grid, dims) -> HeadModel:
    nr, nc, km, jl, jr = grid
    slit = [km * nc + j for j in range(jl + 1, jr)] if jr > jl + 1 else []
    dup = {v: len(skin) + k for k, v in enumerate(slit)}
    verts = [skin, skin[slit]]
    faces = [_grid_faces(nr, nc, km, jl, jr, dup)]
    n_skin = len(skin) + len(slit)
    uc, hw = 0.5 * (lm.corners[0] + lm.corners[1]), 0.5 * (lm.corners[1] - lm.corners[0])
    # lips: the grid band around the slit, between the corners (it follows grid lines, so
    # its edge is smooth); the rows it spans follow the lips' height
    back = np.arange(len(skin) + len(slit))
    back[len(skin) :] = slit
    f0 = back[faces[0]]
    rows, cols = f0 // nc, f0 % nc
    dv = abs(float(skin[(km - 1) * nc + jl, 1] - skin[km * nc + jl, 1])) + 1e-9
    n_up = int(np.clip(round(0.8 * lm.lip_h / dv), 1, 6))
    n_dn = int(np.clip(round(1.0 * lm.lip_h / dv), 1, 6))
    in_cols = (cols.min(1) >= jl) & (cols.max(1) <= jr) & (np.ptp(cols, 1) <= 1)
    in_rows = (rows.min(1) >= km - n_up) & (rows.max(1) <= km + n_dn)
    part = np.where(in_cols & in_rows, 1, 0)
    parts = [part]
    base = n_skin
    for e in lm.eyes:  # eyeballs: the front a little in front of the skin
        sv, sf, facing = _sphere(np.array([e[0], e[1], e[2] - 0.55 * lm.eye_r]), lm.eye_r)
        verts.append(sv)
        faces.append(sf + base)
        fz = facing[sf].mean(1)
        parts.append(np.where(fz > 0.9, 4, 3))
        base += len(sv)
    # the mouth interior: a dark flattened ellipsoid behind the lips
    mv, mf, _ = _sphere(np.array([uc, lm.mouth_v, float(np.median(q[:, 2])) - 0.6 * hw]), 1.0)
    mv = (mv - mv.mean(0)) * [hw * 0.9, lm.lip_h * 2.5, hw * 0.35] + mv.mean(0)
    verts.append(mv)
    faces.append(mf + base)
    parts.append(np.full(len(mf), 5))
    Vq = np.concatenate(verts)
    lower = _lower_weight(Vq, lm, dims, n_skin, list(dup.values()), slit)
    rest = Vq @ R + c
    transfer = _transfer(rest, m, lm, lower)
    colors = _colours(Vq, q, lm, dims, n_skin, np.concatenate(faces), np.concatenate(parts))
    return HeadModel(rest, np.concatenate(faces).astype(np.int32), np.concatenate(parts),
                     tuple(HEAD_COLOURS), transfer, m, lower, R, colors)  # fmt: skip


def _smooth(x: np.ndarray) -> np.ndarray:
    t = np.clip(x, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _colours(V, q, lm: _Landmarks, dims, n_skin: int, faces, part) -> np.ndarray:
    """Per-vertex colours: skin, with lips and brows blended in smoothly; eyeballs white
    with a dark iris facing the viewer; the mouth interior dark."""
    col = {k: np.asarray(v, float) for k, v in HEAD_COLOURS.items()}
    out = np.tile(col["skin"], (len(V), 1))
    S = V[:n_skin]
    uc, hw = 0.5 * (lm.corners[0] + lm.corners[1]), 0.5 * (lm.corners[1] - lm.corners[0])
    lens = lm.lip_h * np.sqrt(np.clip(1 - ((S[:, 0] - uc) / (hw * 1.05)) ** 2, 0, 1))
    front = _smooth((S[:, 2] - dims[4] - 0.4 * dims[3]) / (0.2 * dims[3]))
    lip = _smooth((lens - np.abs(S[:, 1] - lm.mouth_v)) / (0.35 * lm.lip_h + 1e-9)) * front
    out[:n_skin] += lip[:, None] * (col["lips"] - col["skin"])
    if len(lm.brows) >= 2:
        bd = np.min(np.linalg.norm(S[:, None, :2] - q[lm.brows][None, :, :2], axis=-1), 1)
        brow = _smooth((0.45 * lm.eye_r + 2.0 - bd) / (0.3 * lm.eye_r + 1.0)) * front
        out[:n_skin] += brow[:, None] * (col["brows"] - out[:n_skin]) * (1 - lip[:, None])
    for p, name in ((3, "eyes"), (4, "irises"), (5, "mouth")):
        vs = np.unique(faces[part == p])
        vs = vs[vs >= n_skin]
        out[vs] = col[name]
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _lower_weight(V, lm: _Landmarks, dims, n_skin: int, copies, originals) -> np.ndarray:
    """How much each vertex follows the jaw: a step across the mouth slit (upper lip 0,
    lower lip 1), smoothed beyond the corners and toward the back of the head."""
    uc, hw = 0.5 * (lm.corners[0] + lm.corners[1]), 0.5 * (lm.corners[1] - lm.corners[0])
    beyond = np.clip(np.abs(V[:, 0] - uc) - hw, 0, None)
    back = np.clip(dims[4] + 0.6 * dims[3] - V[:, 2], 0, None)
    s = 0.02 * lm.lip_h + 0.6 * beyond + 0.8 * back
    w = 1.0 / (1.0 + np.exp(np.clip((V[:, 1] - lm.mouth_v) / s, -50, 50)))
    w[np.asarray(originals, int)] = 0.0
    w[np.asarray(copies, int)] = 1.0
    w[n_skin:] = np.where(V[n_skin:, 1] < lm.mouth_v - 0.5 * lm.lip_h, w[n_skin:], 0.0)
    return w


def _transfer(rest, m, lm: _Landmarks, lower: np.ndarray) -> np.ndarray:
    """``(N, M)``: the upper face ignores the lower-lip/jaw markers, the lower face the
    upper-lip markers; blended per vertex by ``lower``."""
    M = len(m)

    def sub(drop: np.ndarray) -> np.ndarray:
        keep = np.setdiff1d(np.arange(M), drop)
        A = np.zeros((len(rest), M))
        A[:, keep] = _rbf(rest, m[keep])
        return A

    if len(lm.upper) == 0 or len(lm.lower) == 0 or M - len(lm.lower) < 4:
        return sub(np.zeros(0, int))
    return (1.0 - lower)[:, None] * sub(lm.lower) + lower[:, None] * sub(lm.upper)


@checked
def head_vertices(model: HeadModel, markers: np.ndarray) -> np.ndarray:
    """``(N, 3)`` head vertices for one frame of markers ``(M, 3)``."""
    x = np.asarray(markers, np.float64)
    if x.shape != model.rest_markers.shape:
        raise FxspaceError(f"markers must have shape {model.rest_markers.shape}, got {x.shape}")
    return model.rest + model.transfer @ (x - model.rest_markers)
