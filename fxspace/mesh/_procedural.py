"""Meshes for the paper's range of models (Park, Kang & Kwon, §5, Fig. 9): a skinned mesh
subdivided to a chosen vertex count (the paper's human has 13.8k vertices, the shipped
CesiumMan 3.3k), and a procedurally built long chain that stresses skeleton depth.

- `subdivide_mesh`: ``levels`` rounds of midpoint (1 → 4) subdivision, then, to reach
  ``num_vertices`` exactly, a centroid vertex in the largest triangles (1 → 3, no
  T-junctions). A new vertex's skin weights are interpolated like its position (the mean
  of its edge's or triangle's corners, over the union of their joints), kept to the
  ``max_influences`` largest and renormalised. The skeleton, inverse binds and
  animations are the original's.
- `chain_mesh`: a tube of ``num_joints`` segments along ``+x``, one joint per segment,
  each the child of the previous (depth = ``num_joints``), every ring of vertices
  skinned to the two nearest joints, with a travelling-wave animation (``"wave"``).

Example:

```python
human = fx.mesh.subdivide_mesh(fx.io.read_gltf("CesiumMan.glb"), num_vertices=13800)
chain = fx.mesh.chain_mesh(48)
```
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fxspace._validate import check_int, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.mesh._types import Animation, AnimationChannel, SkinnedMesh

__all__ = ["subdivide_mesh", "chain_mesh"]


def _dense_weights(mesh: SkinnedMesh) -> np.ndarray:
    w = np.zeros((mesh.num_vertices, mesh.num_joints))
    rows = np.repeat(np.arange(mesh.num_vertices), mesh.skin_joints.shape[1])
    np.add.at(w, (rows, np.asarray(mesh.skin_joints).reshape(-1)), mesh.skin_weights.reshape(-1))
    return w


def _sparse_weights(w: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    k = min(k, w.shape[1])
    idx = np.argsort(-w, axis=1, kind="stable")[:, :k]
    ww = np.take_along_axis(w, idx, axis=1)
    ww = ww / np.maximum(ww.sum(axis=1, keepdims=True), 1e-300)
    return idx.astype(np.int32), ww


def _midpoint(v: np.ndarray, w: np.ndarray, f: np.ndarray):
    """One round of 1 → 4 midpoint subdivision (shared edges get one new vertex)."""
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(3, -1).T + v.shape[0]  # (F, 3): the midpoints of edges 01, 12, 20
    v2 = np.concatenate([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
    w2 = np.concatenate([w, 0.5 * (w[uniq[:, 0]] + w[uniq[:, 1]])])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = inv[:, 0], inv[:, 1], inv[:, 2]
    f2 = np.concatenate(
        [
            np.stack([a, ab, ca], 1),
            np.stack([ab, b, bc], 1),
            np.stack([ca, bc, c], 1),
            np.stack([ab, bc, ca], 1),
        ]
    )
    return v2, w2, f2


def _centroids(v: np.ndarray, w: np.ndarray, f: np.ndarray, n: int):
    """A centroid vertex in each of the ``n`` largest triangles (1 → 3)."""
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    pick = np.argsort(-area, kind="stable")[:n]
    c = v.shape[0] + np.arange(n)
    v2 = np.concatenate([v, v[f[pick]].mean(axis=1)])
    w2 = np.concatenate([w, w[f[pick]].mean(axis=1)])
    a, b, cc = f[pick, 0], f[pick, 1], f[pick, 2]
    keep = np.ones(f.shape[0], bool)
    keep[pick] = False
    f2 = np.concatenate(
        [f[keep], np.stack([a, b, c], 1), np.stack([b, cc, c], 1), np.stack([cc, a, c], 1)]
    )
    return v2, w2, f2


@checked
def subdivide_mesh(
    mesh: SkinnedMesh,
    num_vertices: int | None = None,
    levels: int | None = None,
    max_influences: int = 8,
) -> SkinnedMesh:
    """``mesh`` subdivided, with its skin weights interpolated (see the module docstring).

    **Arguments:**

    - `mesh`: a `SkinnedMesh`.
    - `num_vertices`: the vertex count to reach (e.g. 13800, the paper's human); rounds
      of midpoint subdivision are run while they stay below it (unless `levels` is
      given), then centroids fill the rest.
    - `levels`: the rounds of midpoint subdivision (default: as many as fit).
    - `max_influences`: joints kept per vertex (largest weights, renormalised).

    **Returns:** a new `SkinnedMesh` (``name`` suffixed with the vertex count) whose first
    ``V`` vertices and their weights are the original's.
    """
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    k = check_int(max_influences, "max_influences", low=1)
    target = None if num_vertices is None else check_int(num_vertices, "num_vertices", low=1)
    if target is not None and target < v.shape[0]:
        raise FxspaceError(f"num_vertices={target} is below the mesh's {v.shape[0]} vertices")
    if target is None and levels is None:
        raise FxspaceError("give num_vertices (a vertex count to reach) or levels")
    w = _dense_weights(mesh)
    rounds = 0
    while True:
        if levels is not None and rounds >= check_int(levels, "levels", low=0):
            break
        n_edges = len(
            np.unique(np.sort(np.concatenate([f[:, :2], f[:, 1:], f[:, ::-2]]), 1), axis=0)
        )
        if levels is None and v.shape[0] + n_edges > target:
            break
        v, w, f = _midpoint(v, w, f)
        rounds += 1
    if target is not None and target > v.shape[0]:
        if target - v.shape[0] > f.shape[0]:
            raise FxspaceError(
                f"num_vertices={target} needs more centroids than the {f.shape[0]} triangles "
                f"after {rounds} rounds; raise levels"
            )
        v, w, f = _centroids(v, w, f, target - v.shape[0])
    sj, sw = _sparse_weights(w, k)
    return dataclasses.replace(
        mesh,
        name=f"{mesh.name}_{v.shape[0]}",
        vertices=v,
        faces=f.astype(np.int32),
        skin_joints=sj,
        skin_weights=sw,
    )


def chain_mesh(
    num_joints: int = 48,
    ring: int = 8,
    rings_per_joint: int = 2,
    length: float = 1.0,
    radius: float = 0.05,
    amplitude: float = 0.25,
    frames: int = 60,
) -> SkinnedMesh:
    """A skinned tube of ``num_joints`` chained joints along ``+x`` (depth = ``num_joints``).

    **Arguments:** `num_joints` (≥ 2), `ring` vertices around the tube, `rings_per_joint`
    rings of vertices per segment, the tube's `length` and `radius`; the animation
    ``"wave"`` bends every joint about ``z`` and ``y`` by a travelling wave of
    `amplitude` radians over `frames` keys at 30 fps.

    **Returns:** a `SkinnedMesh` (y-up, metres) with one animation.
    """
    nj = check_int(num_joints, "num_joints", low=2)
    ring = check_int(ring, "ring", low=3)
    rpj = check_int(rings_per_joint, "rings_per_joint", low=1)
    seg = check_scalar(length, "length", low=0.0, low_open=True) / nj
    rad = check_scalar(radius, "radius", low=0.0, low_open=True)
    amp = check_scalar(amplitude, "amplitude")
    nf = check_int(frames, "frames", low=2)
    nr = nj * rpj + 1
    x = np.linspace(0.0, nj * seg, nr)
    ang = 2 * np.pi * np.arange(ring) / ring
    verts = np.stack(
        [np.repeat(x, ring), np.tile(rad * np.cos(ang), nr), np.tile(rad * np.sin(ang), nr)], 1
    )
    faces = []
    for r in range(nr - 1):
        a, b = r * ring + np.arange(ring), r * ring + (np.arange(ring) + 1) % ring
        faces += [np.stack([a, b, a + ring], 1), np.stack([b, b + ring, a + ring], 1)]  # outward
    # each ring blends the two joints around it (joint j sits at x = j · seg)
    s = np.clip(x / seg, 0.0, nj - 1)
    j0 = np.minimum(np.floor(s).astype(np.int32), nj - 2)
    t = s - j0
    sj = np.repeat(np.stack([j0, j0 + 1], 1), ring, axis=0)
    sw = np.repeat(np.stack([1.0 - t, t], 1), ring, axis=0)
    rest_t = np.zeros((nj, 3))
    rest_t[1:, 0] = seg
    inv = np.tile(np.eye(4), (nj, 1, 1))
    inv[:, 0, 3] = -seg * np.arange(nj)
    times = np.arange(nf) / 30.0
    phase = 2 * np.pi * (times[:, None] / times[-1] - np.arange(nj)[None, :] / nj)
    half = 0.5 * amp * np.stack([np.sin(phase), 0.5 * np.cos(phase)], -1)  # (T, J, 2): z, y
    q = np.zeros((nf, nj, 4))  # R_z then R_y, as (x, y, z, w)
    cz, sz = np.cos(half[..., 0]), np.sin(half[..., 0])
    cy, sy = np.cos(half[..., 1]), np.sin(half[..., 1])
    q[..., 0], q[..., 1], q[..., 2], q[..., 3] = -sz * sy, cz * sy, sz * cy, cz * cy
    chans = tuple(AnimationChannel(j, "rotation", times, q[:, j], "LINEAR") for j in range(nj))
    return SkinnedMesh(
        name=f"chain{nj}",
        vertices=verts,
        faces=np.concatenate(faces).astype(np.int32),
        joint_names=tuple(f"link{j}" for j in range(nj)),
        joint_nodes=tuple(range(nj)),
        parents=np.arange(-1, nj - 1, dtype=np.int32),
        rest_translations=rest_t,
        rest_rotations=np.tile([0.0, 0.0, 0.0, 1.0], (nj, 1)),
        rest_scales=np.ones((nj, 3)),
        base_transforms=np.tile(np.eye(4), (nj, 1, 1)),
        inverse_bind=inv,
        skin_joints=sj.astype(np.int32),
        skin_weights=sw,
        animations={"wave": Animation("wave", chans)},
    )
