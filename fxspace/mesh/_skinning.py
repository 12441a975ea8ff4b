"""Linear blend skinning (LBS) in JAX (Park, Kang & Kwon, eq. (2); glTF 2.0 §3.7.3).

A vertex ``v`` with joint influences ``(j_i, w_i)`` is posed as

    v' = Σ_i w_i · G_{j_i} · B_{j_i}⁻¹ · [v; 1],

``G_j`` the global transform of joint ``j`` (product of the local transforms from the
root, after the fixed ``base`` transform of the root's non-joint parents) and ``B_j⁻¹``
its inverse bind matrix. Global transforms are computed by a gather-based product along
a padded ancestor table (``(J, D)``, ``D`` = depth + 1): ``D`` batched 4×4 products, no
Python loop over joints, so every function here jit-compiles once per mesh shape and
vmaps over poses.

The IK pose (`Pose`) is a set of XYZ Euler angles per joint, applied *after* the
joint's rest rotation (``R_j = R_rest,j · R_x(θ_x) R_y(θ_y) R_z(θ_z)``), plus a world
translation of the whole skeleton; the zero pose is the rest pose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import _is_tracer, as_float_array, check_indices, check_int, checked
from fxspace.errors import FxspaceError
from fxspace.rotations import euler_to_matrix as _euler_to_matrix
from fxspace.rotations import (
    quat_conj,
    quat_mul,
    quat_normalize,
    quat_to_euler,
    quat_to_matrix,
    quat_xyzw_to_wxyz,
)

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import LocalPose, SkinnedMesh

__all__ = [
    "Pose",
    "quaternion_to_matrix",
    "euler_to_matrix",
    "local_matrices",
    "ancestor_table",
    "global_transforms",
    "skinning_matrices",
    "linear_blend_skinning",
    "skin_local_pose",
    "rest_pose",
    "pose_vertices",
    "pose_from_local",
    "SkinTables",
    "skin_tables",
    "animation_vertices",
    "rest_vertices",
]


class Pose(NamedTuple):
    """IK pose: per-joint XYZ Euler angles relative to the rest rotation + a world translation."""

    angles: Float[Array, "joints 3"]
    translation: Float[Array, " 3"]


def quaternion_to_matrix(q: Float[Array, "*b 4"]) -> Float[Array, "*b 3 3"]:
    """Rotation matrices of (not necessarily unit) quaternions in glTF order ``(x, y, z, w)``."""
    return quat_to_matrix(quat_normalize(q), order="xyzw")


def euler_to_matrix(angles: Float[Array, "*b 3"]) -> Float[Array, "*b 3 3"]:
    """``R_x(θ_0) · R_y(θ_1) · R_z(θ_2)`` (intrinsic XYZ, scipy's ``"XYZ"``)."""
    return _euler_to_matrix(angles, "XYZ")


def local_matrices(
    translations: Float[Array, "*b 3"],
    rotations: Float[Array, "*b 3 3"],
    scales: Float[Array, "*b 3"],
) -> Float[Array, "*b 4 4"]:
    """Local 4×4 transforms ``T · R · S`` (glTF node order)."""
    lin = rotations * scales[..., None, :]
    top = jnp.concatenate([lin, translations[..., :, None]], axis=-1)
    bottom = jnp.broadcast_to(
        jnp.array([0.0, 0.0, 0.0, 1.0], dtype=top.dtype), top.shape[:-2] + (1, 4)
    )
    return jnp.concatenate([top, bottom], axis=-2)


def ancestor_table(parents: np.ndarray) -> np.ndarray:
    """``(J, D)`` int table: row ``j`` = ``j``, its parent, …, its root, then ``J`` (padding).

    ``parents[j]`` must be ``-1`` (root) or a joint index; cycles are refused.
    """
    try:
        p = np.asarray(parents) if not isinstance(parents, str | bytes) else None
    except (TypeError, ValueError):
        p = None
    if p is None or p.ndim != 1 or p.size == 0 or p.dtype.kind not in "iu":
        what = "a string" if p is None else f"{p.dtype} of shape {p.shape}"
        raise FxspaceError(f"parents must be a non-empty 1-D array of joint indices, got {what}")
    parents = p.astype(np.int64)
    n = parents.shape[0]
    if np.any((parents < -1) | (parents >= n)):
        raise FxspaceError("parents must hold -1 (root) or joint indices in [0, J)")
    chains = []
    for j in range(n):
        chain = [j]
        while parents[chain[-1]] >= 0:
            chain.append(int(parents[chain[-1]]))
            if len(chain) > n:
                raise FxspaceError("parents describe a cycle, not a tree")
        chains.append(chain)
    depth = max(len(c) for c in chains) if chains else 1
    table = np.full((n, depth), n, dtype=np.int32)
    for j, c in enumerate(chains):
        table[j, : len(c)] = c
    return table


def global_transforms(
    local: Float[Array, "joints 4 4"],
    ancestors: Int[Array, "joints depth"],
    base: Float[Array, "joints 4 4"],
) -> Float[Array, "joints 4 4"]:
    """Global joint transforms ``G_j = base_{root(j)} · L_root ⋯ L_parent(j) · L_j``.

    ``ancestors`` is `ancestor_table` (padded with ``J``; only its parent column is
    used); ``base`` holds, per joint, the fixed transform above its root (``base[root(j)]``
    for every ``j`` — see `chain_bases`). Pointer jumping: after step ``s`` each
    joint holds the product of the ``2^s`` links above it, so ``⌈log₂ D⌉`` batched products
    of ``J`` 4×4 matrices replace a pass per level (``D`` = depth + 1).
    """
    nj, depth = ancestors.shape
    eye = jnp.eye(4, dtype=local.dtype)[None]
    pad = jnp.asarray([nj], dtype=ancestors.dtype)
    ptr = ancestors[:, 1] if depth > 1 else jnp.full((nj,), nj, ancestors.dtype)
    g = local
    for _ in range(int(np.ceil(np.log2(depth))) if depth > 1 else 0):
        g = jnp.concatenate([g, eye], axis=0)[ptr] @ g
        ptr = jnp.concatenate([ptr, pad])[ptr]
    return base @ g


def chain_bases(base_transforms: np.ndarray, ancestors: np.ndarray) -> np.ndarray:
    """Per joint, the base transform of its root (numpy, ``(J, 4, 4)``)."""
    nj = ancestors.shape[0]
    roots = np.array([row[row < nj][-1] for row in ancestors], dtype=np.int64)
    return np.asarray(base_transforms, dtype=np.float64)[roots]


@checked
def skinning_matrices(
    global_: Float[Array, "joints 4 4"], inverse_bind: Float[Array, "joints 4 4"]
) -> Float[Array, "joints 4 4"]:
    """``A_j = G_j · B_j⁻¹``."""
    return global_ @ inverse_bind


def linear_blend_skinning(
    vertices: Float[Array, "verts 3"],
    skin_joints: Int[Array, "verts influences"],
    skin_weights: Float[Array, "verts influences"],
    skin_mats: Float[Array, "joints 4 4"],
) -> Float[Array, "verts 3"]:
    """Posed vertices ``v' = Σ_i w_i A_{j_i} [v; 1]`` (LBS, the paper's eq. (2)).

    Blends the matrices first (``Σ_i w_i A_{j_i}``, ``V·I`` 3×4 sums) then applies one
    affine map per vertex: O(V·I) work. Vmap over ``skin_mats`` for many poses.
    """
    vertices = as_float_array(vertices, "vertices", shape=(None, 3), finite="allow")
    skin_mats = as_float_array(skin_mats, "skin_mats", shape=(None, 4, 4), finite="allow")
    skin_weights = as_float_array(skin_weights, "skin_weights", ndim=2, finite="allow")
    if skin_weights.shape[0] != vertices.shape[0]:
        raise FxspaceError(
            f"skin_weights must be (verts={vertices.shape[0]}, influences), "
            f"got {skin_weights.shape}"
        )
    if not _is_tracer(skin_joints):
        j = check_indices(np.ravel(skin_joints), "skin_joints", skin_mats.shape[0])
        skin_joints = j.reshape(np.shape(skin_joints)).astype(np.int32)
    if tuple(np.shape(skin_joints)) != skin_weights.shape:
        raise FxspaceError(
            f"skin_joints must have the shape of skin_weights {skin_weights.shape}, "
            f"got {np.shape(skin_joints)}"
        )
    a = skin_mats[:, :3, :]  # (J, 3, 4)
    blended = jnp.einsum("vi,virc->vrc", skin_weights, a[skin_joints])
    return jnp.einsum("vrc,vc->vr", blended[:, :, :3], vertices) + blended[:, :, 3]


class SkinTables(NamedTuple):
    """The pose-independent tables that skinning needs beyond the mesh, computed once by
    `skin_tables` and passed explicitly (nothing is cached on the mesh).

    - ``ancestors``: `ancestor_table` of the skeleton, ``(J, D)`` padded with ``J``;
    - ``base``: per joint, the fixed transform above its root (`chain_bases`).
    """

    ancestors: Int[Array, "joints depth"]
    base: Float[Array, "joints 4 4"]


@checked
def skin_tables(mesh: SkinnedMesh) -> SkinTables:
    """The `SkinTables` of ``mesh`` (host side, numpy; cheap: one pass over the joints)."""
    anc = ancestor_table(mesh.parents)
    return SkinTables(anc, chain_bases(np.asarray(mesh.base_transforms), anc))


def _lbs(mesh: SkinnedMesh, tables: SkinTables, local: Array) -> Array:
    g = global_transforms(local, tables.ancestors, tables.base)
    return linear_blend_skinning(
        mesh.vertices, mesh.skin_joints, mesh.skin_weights, skinning_matrices(g, mesh.inverse_bind)
    )


@jax.jit
def _skin_trs(mesh: SkinnedMesh, tables: SkinTables, t, q, s):
    def one(t1, q1, s1):
        return _lbs(mesh, tables, local_matrices(t1, quaternion_to_matrix(q1), s1))

    return jax.vmap(one)(t, q, s)


@checked
def skin_local_pose(
    mesh: SkinnedMesh, pose: LocalPose, tables: SkinTables | None = None
) -> Float[Array, "*b verts 3"]:
    """Skinned vertices of ``mesh`` for local joint transforms ``pose`` (leading axes ``(*b, J)``).

    Jitted and vmapped over the leading axes: ``(J, ·)`` → ``(V, 3)``, ``(T, J, ·)`` →
    ``(T, V, 3)``. `tables` (`skin_tables`) may be passed to skip their computation.
    """
    t = jnp.asarray(pose.translations)
    q = jnp.asarray(pose.rotations)
    s = jnp.asarray(pose.scales)
    nj = mesh.num_joints
    if t.shape[-2:] != (nj, 3) or q.shape[-2:] != (nj, 4) or s.shape[-2:] != (nj, 3):
        raise FxspaceError(
            f"pose shapes {t.shape}/{q.shape}/{s.shape} do not match the mesh's {nj} joints "
            "(translations (..., J, 3), rotations (..., J, 4), scales (..., J, 3))"
        )
    batch = t.shape[:-2]
    tables = skin_tables(mesh) if tables is None else tables
    out = _skin_trs(
        mesh, tables, t.reshape((-1, nj, 3)), q.reshape((-1, nj, 4)), s.reshape((-1, nj, 3))
    )
    return out.reshape(batch + out.shape[1:])


@checked
def animation_vertices(
    mesh: SkinnedMesh, animation: str | int, times: np.ndarray | float
) -> np.ndarray:
    """Posed (skinned) vertices of ``mesh``'s animation ``animation`` at ``times``.

    The stable way to get dense vertex sequences from a glTF animation: samples the
    animation (`SkinnedMesh.sample_animation`) and applies linear blend skinning
    (`skin_local_pose`, jitted and vmapped over the times). Uses float64 when
    ``jax_enable_x64`` is on, else float32.

    **Returns:** ``(T, V, 3)`` float64 numpy (``(V, 3)`` for a scalar time).
    """
    pose = mesh.sample_animation(animation, times)
    return np.asarray(skin_local_pose(mesh, pose), dtype=np.float64)


@checked
def rest_vertices(mesh: SkinnedMesh) -> np.ndarray:
    """Vertices skinned at the rest pose (equal to the bind pose for consistent files)."""
    return np.asarray(skin_local_pose(mesh, mesh.rest_pose()), dtype=np.float64)


@checked
def rest_pose(num_joints: int | SkinnedMesh, dtype=None) -> Pose:
    """The zero `Pose` (rest rotations, no translation)."""
    if isinstance(num_joints, int | np.integer) and not isinstance(num_joints, bool):
        nj = check_int(num_joints, "num_joints", low=0)
    elif hasattr(num_joints, "num_joints"):
        nj = num_joints.num_joints
    elif hasattr(num_joints, "ancestors"):  # an IKModel
        nj = int(num_joints.ancestors.shape[0])
    else:
        raise FxspaceError(
            "num_joints must be a joint count, a SkinnedMesh or an IKModel, got "
            f"{type(num_joints).__name__}"
        )
    dtype = dtype or jnp.result_type(float)
    return Pose(jnp.zeros((nj, 3), dtype), jnp.zeros((3,), dtype))


@jax.jit
def _pose_vertices(mesh: SkinnedMesh, tables: SkinTables, angles, translation):
    rest_r = quaternion_to_matrix(mesh.rest_rotations)
    local = local_matrices(
        mesh.rest_translations, rest_r @ euler_to_matrix(angles), mesh.rest_scales
    )
    return _lbs(mesh, tables, local) + translation[None, :]


@checked
def pose_vertices(
    mesh: SkinnedMesh, pose: Pose, tables: SkinTables | None = None
) -> Float[Array, "verts 3"]:
    """Skinned vertices of ``mesh`` at the IK `Pose` ``pose`` (one pose; vmap for many);
    `tables` (`skin_tables`) may be passed to skip their computation."""
    tables = skin_tables(mesh) if tables is None else tables
    return _pose_vertices(mesh, tables, pose.angles, pose.translation)


@checked
def pose_from_local(mesh: SkinnedMesh, pose: LocalPose) -> Pose:
    """The IK `Pose` closest to local transforms ``pose`` (leading axes kept).

    Angles: XYZ Euler angles of ``R_rest⁻¹ · R`` per joint. Translation: the world offset
    that puts the first joint carrying skin weight (the hip, usually) where ``pose`` puts
    it, so a translated root *or* hip is represented. Other joint translation and scale
    changes are not representable in the IK pose and are dropped.
    """
    q = np.asarray(pose.rotations, dtype=np.float64)
    batch = q.shape[:-2]
    nj = mesh.num_joints
    nb = int(np.prod(batch, dtype=int))
    rest = quat_normalize(quat_xyzw_to_wxyz(np.tile(mesh.rest_rotations, (nb, 1))))
    cur = quat_normalize(quat_xyzw_to_wxyz(q.reshape(-1, 4)))
    rel = quat_mul(quat_conj(rest), cur)
    angles = quat_to_euler(rel, "XYZ", degrees=False).reshape((nb, nj, 3))
    used = np.zeros(nj, dtype=bool)
    used[np.asarray(mesh.skin_joints)[np.asarray(mesh.skin_weights) > 0]] = True
    k = int(np.flatnonzero(used)[0]) if used.any() else 0
    tables = skin_tables(mesh)
    anc, base = jnp.asarray(tables.ancestors), jnp.asarray(tables.base)
    rest_r = quaternion_to_matrix(jnp.asarray(mesh.rest_rotations))
    rest_t, rest_s = jnp.asarray(mesh.rest_translations), jnp.asarray(mesh.rest_scales)

    def origin_true(t, qq, s):
        return global_transforms(local_matrices(t, quaternion_to_matrix(qq), s), anc, base)[
            k, :3, 3
        ]

    def origin_pose(a):
        return global_transforms(
            local_matrices(rest_t, rest_r @ euler_to_matrix(a), rest_s), anc, base
        )[k, :3, 3]

    t_true = jax.vmap(origin_true)(
        jnp.asarray(pose.translations).reshape(nb, nj, 3),
        jnp.asarray(q).reshape(nb, nj, 4),
        jnp.asarray(pose.scales).reshape(nb, nj, 3),
    )
    a = jnp.asarray(angles)
    trans = t_true - jax.vmap(origin_pose)(a)
    return Pose(a.reshape(batch + (nj, 3)), trans.reshape(batch + (3,)))
