"""Binding a capture to a rig: the similarity that puts the markers on the head, and each
marker's point on a face triangle.

From a neutral frame of a capture, `bind_markers`

1. pairs the named markers that have a landmark counterpart (eye corners, mouth corners
   and centres, nose, chin, brows: `LANDMARKS`, Multi-PIE's 68-point numbering, which
   the ICT Face Model lists as vertex indices) and fits the similarity
   ``y = s R x + t`` (Umeyama, 1991: least squares, no reflection);
2. refines it by iterated closest points: every marker to its closest point on the face
   triangles, the similarity re-fitted to those points and the landmark pairs together;
   optionally (``identity=True``) the identity modes are fitted too (ridge least squares
   on the bound points), so the head takes the performer's proportions;
3. binds every marker to its closest point (triangle + barycentric coordinates), and
   reports the distance; a marker farther than ``max_distance`` is refused by name.

``bind_markers(rig, vertex_ids=ids)`` binds markers placed at rig vertices (synthetic
takes, tests): the identity similarity, each marker at its vertex.

Example:

```python
take = fx.io.read_markers(fx.data.data_path("face", "animface_jaw.c3d"))
b = fx.face.bind_markers(rig, take.positions[0], take.names)
b.distance_mm = b.distance / b.scale      # per marker, in the capture's units
```
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.face._rig import Rig
from fxspace.rigid import fit_similarity

__all__ = ["Binding", "bind_markers", "LANDMARKS", "closest_points", "similarity_fit"]

#: marker name (lower-case; the AnimFace and common mocap spellings) → Multi-PIE
#: 68-point landmark index (0-based; the subject's left is the image's right)
LANDMARKS: dict[str, int] = {
    "chin": 8,
    "reyebrow_outside": 17,
    "reyebrow_m": 19,
    "reyebrow_inside": 21,
    "leyebrow_inside": 22,
    "leyebrow_m": 24,
    "leyebrow_outside": 26,
    "nosetop": 27,
    "nosehead": 30,
    "reye_outside": 36,
    "reye_inside": 39,
    "leye_inside": 42,
    "leye_outside": 45,
    "mouth_rend": 48,
    "mouth_up": 51,
    "mouth_lend": 54,
    "mouth_down": 57,
}


class Binding(NamedTuple):
    """Markers bound to a rig (see `bind_markers`).

    ``triangles`` ``(M,)`` and ``barycentric`` ``(M, 3)``: each marker's point on the
    rig; ``corners`` ``(M, 3)`` the triangles' vertex indices; ``scale``, ``rotation``
    ``(3, 3)``, ``translation`` ``(3,)``: the similarity from the capture's frame and
    units into the rig's (``y = s R x + t``); ``distance`` ``(M,)``: each marker's
    distance from its point, in rig units (``distance / scale`` in the capture's);
    ``names``; ``identity`` ``(I,)``: the identity-mode coefficients (zeros unless
    fitted); ``points`` ``(M, 3)``: the neutral markers in the rig's frame (each rides on
    its triangle point with its offset from the surface kept);
    ``basis`` ``(K, M, 3)``: each shape's delta at the bound points; ``units``: the
    capture's length unit when known (``"mm"``…; ``None`` when not given), so that
    `solve_weights` converts a take in other units or refuses it.
    """

    triangles: np.ndarray
    barycentric: np.ndarray
    corners: np.ndarray
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    distance: np.ndarray
    names: tuple[str, ...]
    identity: np.ndarray
    points: np.ndarray
    basis: np.ndarray
    units: str | None = None

    @property
    def size(self) -> float:
        """The bound face's size: the RMS distance of the neutral markers from their
        centroid, in rig units (``size / scale`` in the capture's). The solve judges its
        residual against it."""
        P = np.asarray(self.points, np.float64)
        return float(np.sqrt(np.mean(np.sum((P - P.mean(0)) ** 2, axis=1))))

    def to_rig(self, markers):
        """Capture-space markers ``(..., M, 3)`` in the rig's frame and units."""
        X = jnp.asarray(markers)
        t = jnp.asarray(self.translation).reshape((1,) * (X.ndim - 1) + (3,))
        return self.scale * X @ jnp.asarray(self.rotation).T + t


def similarity_fit(src, dst, weights=None) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama's least-squares similarity ``dst ≈ s R src + t`` (``det R = +1``), in
    float64: `fxspace.rigid.fit_similarity`, kept under its name and ``(s, R, t)`` order."""
    w = None if weights is None else np.asarray(weights, np.float64)
    R, s, t = fit_similarity(np.asarray(src, np.float64), np.asarray(dst, np.float64), w)
    return float(s), R, t


def closest_points(points, vertices, faces, candidates: int = 48):
    """For each point, the closest point on the triangles ``faces`` of ``vertices``:
    ``(triangle index, barycentric (3,), distance)`` (Ericson, Real-Time Collision
    Detection §5.1.5). The exact test runs on the `candidates` triangles whose centroids
    are nearest (a k-d tree), and on every triangle whose bounding sphere could still
    hold a closer point."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, np.float64)
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    tri = V[F]  # (F, 3, 3)
    cen = tri.mean(axis=1)
    rad = np.max(np.linalg.norm(tri - cen[:, None], axis=-1), axis=1)
    k = min(candidates, len(F))
    _, idx = cKDTree(cen).query(P, k=k)
    idx = np.asarray(idx).reshape(len(P), k)
    t, b, d = _closest_among(P, tri, idx)
    # a triangle can be closer than the k-th nearest centroid only if its bounding sphere
    # reaches inside the current distance: check those exhaustively (rare)
    reach = np.linalg.norm(cen[None] - P[:, None], axis=-1) - rad[None] < d[:, None]
    for i in np.flatnonzero(reach.sum(axis=1) > k):
        ti, bi, di = _closest_among(P[i : i + 1], tri, np.flatnonzero(reach[i])[None])
        if di[0] < d[i]:
            t[i], b[i], d[i] = ti[0], bi[0], di[0]
    return t, b, d


def _closest_among(P, tri, idx):
    a, b, c = tri[idx, 0], tri[idx, 1], tri[idx, 2]  # (M, k, 3)
    bary = _closest_on_triangles(P[:, None, :], a, b, c)
    q = bary[..., :1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
    d = np.linalg.norm(q - P[:, None, :], axis=-1)
    j = np.argmin(d, axis=1)
    rows = np.arange(len(P))
    return idx[rows, j], bary[rows, j], d[rows, j]


def _closest_on_triangles(p, a, b, c):
    """Barycentric coordinates of the closest point of triangle ``abc`` to ``p``
    (broadcast over leading axes)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.sum(ab * ap, -1), np.sum(ac * ap, -1)
    bp = p - b
    d3, d4 = np.sum(ab * bp, -1), np.sum(ac * bp, -1)
    cp = p - c
    d5, d6 = np.sum(ab * cp, -1), np.sum(ac * cp, -1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    out = np.stack([1.0 - v_in - w_in, v_in, w_in], -1)
    z = np.zeros_like(d1)
    o = np.ones_like(d1)

    def put(mask, u, v, w):
        nonlocal out
        out = np.where(mask[..., None], np.stack([u, v, w], -1), out)

    put((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1 - t_ab, t_ab, z)  # edge ab
    put((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1 - t_ac, z, t_ac)  # edge ac
    put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), z, 1 - t_bc, t_bc)  # edge bc
    put((d1 <= 0) & (d2 <= 0), o, z, z)  # vertex a
    put((d3 >= 0) & (d4 <= d3), z, o, z)  # vertex b
    put((d6 >= 0) & (d5 <= d6), z, z, o)  # vertex c
    return np.nan_to_num(out, nan=1.0 / 3.0)


def _vertex_binding(rig: Rig, vertex_ids, names, units=None) -> Binding:
    ids = np.asarray(vertex_ids)
    if ids.ndim != 1 or len(ids) < 3 or not np.issubdtype(ids.dtype, np.integer):
        raise FxspaceError(f"vertex_ids must be a 1-D integer array of >= 3 vertices; got {ids!r}")
    if ids.min() < 0 or ids.max() >= rig.num_vertices:
        raise FxspaceError(
            f"vertex_ids must lie in [0, {rig.num_vertices}); got {ids.min()}..{ids.max()}"
        )
    F = np.asarray(rig.faces)
    first = np.full(rig.num_vertices, -1)
    for corner in (2, 1, 0):
        first[F[:, corner]] = np.arange(len(F))
    tri = first[ids]
    if np.any(tri < 0):
        raise FxspaceError(f"vertex_ids {ids[tri < 0][:5].tolist()} are on no triangle")
    bary = (F[tri] == ids[:, None]).astype(np.float64)
    if len(np.unique(ids)) != len(ids):
        raise FxspaceError("vertex_ids must be distinct: two markers at one vertex")
    names = tuple(str(n) for n in names) if names is not None else tuple(f"v{i}" for i in ids)
    if len(names) != len(ids):
        raise FxspaceError(f"names must give one name per vertex id ({len(ids)}); got {len(names)}")
    _check_unique(names)
    _check_spread(np.asarray(rig.neutral, np.float64)[ids], "vertex_ids")
    return _finish(rig, tri, bary, 1.0, np.eye(3), np.zeros(3), np.zeros(len(ids)), names,
                   np.zeros(rig.identity.shape[0]), units=units)  # fmt: skip


def _finish(rig, tri, bary, s, R, t, dist, names, coeffs, at=None, units=None) -> Binding:
    F = np.asarray(rig.faces)
    corners = F[tri]
    base = np.asarray(rig.neutral, np.float64)
    if len(coeffs):
        base = base + np.einsum("i,inc->nc", coeffs, np.asarray(rig.identity, np.float64))
    # each marker rides on its triangle with its offset from the surface kept (markers
    # sit on the skin, a few millimetres off the generic head): at the neutral frame the
    # model is exactly the bound markers
    points = np.einsum("mj,mjc->mc", bary, base[corners]) if at is None else np.asarray(at)
    D = np.asarray(rig.deltas, np.float64)
    basis = np.einsum("mj,kmjc->kmc", bary, D[:, corners])
    return Binding(tri, bary, corners, float(s), np.asarray(R), np.asarray(t), np.asarray(dist),
                   tuple(names), np.asarray(coeffs), points, basis, units)  # fmt: skip


def _landmark_pairs(rig: Rig, names) -> tuple[np.ndarray, np.ndarray]:
    lm = rig.vertex_sets.get("landmarks")
    if lm is None:
        raise FxspaceError(
            "this rig has no 'landmarks' vertex set; pass vertex_ids= or a rig folder with "
            "vertex_indices.json (idx_to_landmark_verts)"
        )
    lm = np.asarray(lm)
    idx, verts = [], []
    for i, n in enumerate(names):
        k = LANDMARKS.get(str(n).lower())
        if k is not None and k < len(lm):
            idx.append(i)
            verts.append(int(lm[k]))
    if len(idx) < 4:
        raise FxspaceError(
            f"only {len(idx)} markers have a landmark counterpart (need >= 4: eye and mouth "
            f"corners, nose, chin, brows named as in fx.face.LANDMARKS: {sorted(LANDMARKS)[:6]} …)"
        )
    return np.asarray(idx), np.asarray(verts)


def _check_markers(neutral_markers, names) -> tuple[np.ndarray, tuple[str, ...]]:
    X = np.asarray(neutral_markers, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) < 4:
        raise FxspaceError(f"neutral_markers must be (M, 3) with M >= 4; got {X.shape}")
    if names is None or len(names) != len(X):
        raise FxspaceError("names must give one marker name per row of neutral_markers")
    names = tuple(str(n) for n in names)
    _check_unique(names)
    bad = [names[i] for i in np.flatnonzero(~np.all(np.isfinite(X), axis=1))]
    if bad:
        raise FxspaceError(
            f"markers {bad[:5]} are missing (NaN) in the neutral frame; pick a frame where "
            "every marker is seen (e.g. the first complete one)"
        )
    _check_spread(X, "neutral_markers")
    return X, names


def _check_unique(names) -> None:
    """Refuse duplicated marker names (each would be blamed for the other's error)."""
    seen: dict[str, int] = {}
    for n in names:
        seen[n] = seen.get(n, 0) + 1
    dup = sorted(n for n, c in seen.items() if c > 1)
    if dup:
        raise FxspaceError(
            f"marker names must be unique; repeated: {dup[:5]} — rename the duplicates "
            "(each marker is bound, solved and reported by its name)"
        )


def _check_spread(X: np.ndarray, what: str) -> None:
    """Refuse a degenerate neutral frame: every marker at one point, or on one line (no
    similarity, no face size to judge a fit against)."""
    C = X - X.mean(0)
    sv = np.linalg.svd(C, compute_uv=False)
    if not sv[0] > 0 or sv[1] <= 1e-6 * sv[0]:
        shape = "at one point" if not sv[0] > 0 else "on one line"
        raise FxspaceError(
            f"{what}: all {len(X)} markers lie {shape}: a degenerate neutral frame binds "
            "nothing; pass a frame where the markers spread over the face"
        )


def bind_markers(
    rig: Rig,
    neutral_markers=None,
    names=None,
    *,
    vertex_ids=None,
    identity: bool = False,
    max_distance: float | None = None,
    part: str = "face",
    iterations: int = 15,
    identity_ridge: float = 1.0,
    units: str | None = None,
) -> Binding:
    """Bind a capture's markers to ``rig`` (see the module docstring).

    **Arguments:** `rig`: a `Rig`; `neutral_markers` ``(M, 3)``: one neutral frame of the
    capture, any units; `names` (``M``): the marker names (`LANDMARKS` pairs the ones
    with a landmark counterpart); or `vertex_ids`: markers at those rig vertices, in rig
    units. `identity`: also fit the identity modes; `max_distance`: refuse a marker
    farther than this from the surface after the fit, in rig units (default: 12 % of
    the distance between the outer eye corners, ≈ 1.1 cm on the ICT head); `part`: the
    vertex set whose triangles markers bind to (``"face"``; all triangles when the rig
    has no such set); `iterations`: closest-point refinements; `units`: the capture's
    length unit (``"mm"``, ``"cm"``, ``"m"``…; taken from a `MarkerSequence` frame's
    sequence when you pass ``seq.units``): a take solved later in other units is then
    converted (or refused when the units are unknown and its size disagrees).

    Refused: duplicated marker names, a neutral frame with a missing marker, a
    degenerate neutral frame (every marker at one point or on one line).

    **Returns:** a `Binding`.
    """
    if not isinstance(rig, Rig):
        raise FxspaceError("rig must be a fx.face.Rig (from fx.face.read_rig)")
    units = _units_arg(units)
    if vertex_ids is not None:
        if neutral_markers is not None:
            raise FxspaceError("pass either neutral_markers (+ names) or vertex_ids, not both")
        return _vertex_binding(rig, vertex_ids, names, units)
    if neutral_markers is None:
        raise FxspaceError("pass neutral_markers (M, 3) with their names, or vertex_ids")
    X, names = _check_markers(neutral_markers, names)
    li, lv = _landmark_pairs(rig, names)
    base = np.asarray(rig.neutral, np.float64)
    Id = np.asarray(rig.identity, np.float64)
    coeffs = np.zeros(len(Id))
    s, R, t = similarity_fit(X[li], base[lv])
    F = np.asarray(rig.faces)[rig.face_triangles(part)]
    for _ in range(iterations):
        mesh = base + np.einsum("i,inc->nc", coeffs, Id) if len(coeffs) else base
        Y = s * X @ R.T + t
        tri, bary, _ = closest_points(Y, mesh, F)
        C = np.einsum("mj,mjc->mc", bary, mesh[F[tri]])
        src = np.concatenate([X, X[li]])
        dst = np.concatenate([C, mesh[lv]])
        s, R, t = similarity_fit(src, dst)
        if identity and len(Id):
            Y = s * X @ R.T + t
            P0 = np.einsum("mj,mjc->mc", bary, base[F[tri]])
            Pi = np.einsum("mj,imjc->imc", bary, Id[:, F[tri]]).reshape(len(Id), -1)
            rhs = (Y - P0).reshape(-1)
            coeffs = np.linalg.solve(Pi @ Pi.T + identity_ridge * np.eye(len(Id)), Pi @ rhs)
    mesh = base + np.einsum("i,inc->nc", coeffs, Id) if len(coeffs) else base
    Y = s * X @ R.T + t
    tri, bary, dist = closest_points(Y, mesh, F)
    lm = np.asarray(rig.vertex_sets["landmarks"])
    if max_distance is None:
        max_distance = 0.12 * float(np.linalg.norm(base[lm[36]] - base[lm[45]]))
    far = np.flatnonzero(dist > max_distance)
    if len(far):
        worst = ", ".join(f"{names[i]} ({dist[i]:.3g})" for i in far[np.argsort(-dist[far])][:5])
        raise FxspaceError(
            f"markers land nowhere near the face after the fit: {worst} rig units from the "
            f"surface (max_distance={max_distance:.3g}); check the marker names and the "
            "neutral frame, drop those markers, or raise max_distance"
        )
    tri = np.asarray(rig.face_triangles(part))[tri]
    return _finish(rig, tri, bary, s, R, t, dist, names, coeffs, at=Y, units=units)


def _units_arg(units) -> str | None:
    """A length unit's `UNIT_SCALES` key (``"Millimeters"`` → ``"mm"``), or None."""
    from fxspace.io import UNIT_SCALES

    if units is None:
        return None
    u = units.strip().lower() if isinstance(units, str) else ""
    alias = {"millimeters": "mm", "millimetres": "mm", "centimeters": "cm", "centimetres": "cm",
             "meters": "m", "metres": "m", "inches": "in", "inch": "in", "feet": "ft"}  # fmt: skip
    u = alias.get(u, u)
    if u not in UNIT_SCALES:
        raise FxspaceError(
            f"units must be a length unit {sorted(UNIT_SCALES)} (or None); got {units!r}"
        )
    return u
