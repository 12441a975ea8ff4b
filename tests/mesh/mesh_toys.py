"""Small skinned meshes and poses with known answers, shared by the mesh-IK tests."""

import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.io import SkinnedMesh


def branching_mesh(seed: int = 0, uniform_scale: float = 1.0, parents=None) -> SkinnedMesh:
    """A random 6-joint tree (one branch point, one uniformly scaled joint; or the tree
    ``parents``), with vertices scattered around the joints and skinned to each joint and
    its parent."""
    rng = np.random.default_rng(seed)
    if parents is None:
        parents = [-1, 0, 1, 1, 3, 2]
    parents = np.asarray(parents, dtype=np.int32)
    nj = parents.size
    t = rng.normal(0, 1, (nj, 3))
    q = Rotation.random(nj, random_state=seed).as_quat()
    s = np.ones((nj, 3))
    s[min(3, nj - 1)] = uniform_scale
    local = np.tile(np.eye(4), (nj, 1, 1))
    local[:, :3, :3] = Rotation.from_quat(q).as_matrix() * s[:, None, :]
    local[:, :3, 3] = t
    glob = np.zeros_like(local)
    for j in range(nj):
        glob[j] = local[j] if parents[j] < 0 else glob[parents[j]] @ local[j]
    per = 12
    verts, joints, weights = [], [], []
    for j in range(nj):
        verts.append(glob[j, :3, 3] + rng.normal(0, 0.5, (per, 3)))
        w = rng.uniform(0.5, 1.0, per)
        p = max(parents[j], 0)
        joints.append(np.stack([np.full(per, j), np.full(per, p)], axis=1))
        weights.append(np.stack([w, 1 - w], axis=1))
    v = np.concatenate(verts)
    faces = np.array([rng.choice(v.shape[0], 3, replace=False) for _ in range(120)], np.int32)
    return SkinnedMesh(
        name="branching",
        vertices=v,
        faces=faces,
        joint_names=tuple(f"j{i}" for i in range(nj)),
        joint_nodes=tuple(range(nj)),
        parents=parents,
        rest_translations=t,
        rest_rotations=q,
        rest_scales=s,
        base_transforms=np.tile(np.eye(4), (nj, 1, 1)),
        inverse_bind=np.linalg.inv(glob),
        skin_joints=np.concatenate(joints).astype(np.int32),
        skin_weights=np.concatenate(weights),
        animations={},
    )


def random_pose(rng, nj, scale=0.3, trans=0.2):
    return fx.Pose(jnp.asarray(rng.normal(0, scale, (nj, 3))), jnp.asarray(rng.normal(0, trans, 3)))


def both_views(mesh, k_front, k_back, seed=0):
    a = fx.place_markers(mesh.vertices, mesh.faces, k_front, (0.0, 0.0, -1.0), seed=seed)
    b = fx.place_markers(mesh.vertices, mesh.faces, k_back, (0.0, 0.0, 1.0), seed=seed + 1)
    return fx.MarkerSet(
        jnp.concatenate([a.triangles, b.triangles]), jnp.concatenate([a.barycentric, b.barycentric])
    )


def _rel(a, b):
    return max(
        float(jnp.max(jnp.abs(x - y)) / jnp.max(jnp.abs(y))) for x, y in zip(a, b, strict=True)
    )


def _flat(pose):
    """A pose as one vector: the angles, then the translation."""
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


def _unflat(x, nj):
    return fx.Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :])
