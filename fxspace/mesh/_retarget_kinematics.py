"""Kinematics of retargeting, host side (numpy): the source's and the character's world
frames, the joint-origin IK model, skeleton path lengths, and the baseline rotation copy
(``R_c = R_s Q R_c,rest``, ``Q`` turning the character's rest bones onto the source's).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from fxspace.mesh._ik_model import ik_model
from fxspace.mesh._markers import MarkerSet
from fxspace.mesh._retarget_inputs import RetargetError
from fxspace.mesh._skinning import Pose
from fxspace.rigid import fit_rotation
from fxspace.rotations import quat_normalize, quat_to_matrix

__all__ = ["joint_positions"]


# --------------------------------------------------------------------------- kinematics


def _source_fk(parents, off, root, rot):
    """World positions ``(T, J, 3)`` and rotations ``(T, J, 3, 3)`` (the Motion rules)."""
    r_local = np.asarray(quat_to_matrix(quat_normalize(rot)))
    t, nj = rot.shape[:2]
    rw = np.empty((t, nj, 3, 3))
    x = np.empty((t, nj, 3))
    for j in range(nj):
        p = parents[j]
        if p < 0:
            rw[:, j] = r_local[:, j]
            x[:, j] = root + off[j]
        else:
            rw[:, j] = rw[:, p] @ r_local[:, j]
            x[:, j] = x[:, p] + np.einsum("tab,b->ta", rw[:, p], off[j])
    return x, rw


def _char_rest(mesh):
    """Rest global transforms ``(J, 4, 4)`` of the character (base transforms included)."""
    q = np.asarray(mesh.rest_rotations, np.float64)
    r = np.asarray(quat_to_matrix(quat_normalize(q), order="xyzw"))
    nj = mesh.num_joints
    loc = np.tile(np.eye(4), (nj, 1, 1))
    loc[:, :3, :3] = r * np.asarray(mesh.rest_scales, np.float64)[:, None, :]
    loc[:, :3, 3] = mesh.rest_translations
    g = np.empty_like(loc)
    par = np.asarray(mesh.parents)
    for j in range(nj):
        g[j] = (np.asarray(mesh.base_transforms[j]) @ loc[j]) if par[j] < 0 else g[par[j]] @ loc[j]
    return g, loc


def _global_frames_np(mesh, angles, translation):
    """Character global transforms at IK poses, numpy: ``(T, J, 4, 4)``."""
    _, loc = _char_rest(mesh)
    e = _euler_xyz(angles)  # (T, J, 3, 3)
    t, nj = angles.shape[:2]
    lp = np.broadcast_to(loc, (t, nj, 4, 4)).copy()
    s = np.asarray(mesh.rest_scales, np.float64)
    rr = loc[:, :3, :3] / s[:, None, :]
    lp[..., :3, :3] = rr @ e * s[:, None, :]
    g = np.empty_like(lp)
    par = np.asarray(mesh.parents)
    for j in range(nj):
        g[:, j] = (mesh.base_transforms[j] @ lp[:, j]) if par[j] < 0 else g[:, par[j]] @ lp[:, j]
    g[..., :3, 3] += translation[:, None, :]
    return g


def joint_positions(mesh, pose: Pose) -> np.ndarray:
    """World positions ``(T, J, 3)`` of ``mesh``'s joints at the IK poses ``pose``
    (leading frame axis; numpy, host side)."""
    if not hasattr(mesh, "joint_names") or not hasattr(mesh, "inverse_bind"):
        raise RetargetError(
            f"mesh must be a SkinnedMesh (fx.io.read_gltf), got {type(mesh).__name__}"
        )
    if not isinstance(pose, Pose):
        raise RetargetError(f"pose must be a Pose (fx.mesh.Pose), got {type(pose).__name__}")
    a = np.asarray(pose.angles, np.float64)
    tr = np.asarray(pose.translation, np.float64)
    one = a.ndim == 2
    if one:
        a, tr = a[None], tr[None]
    x = _global_frames_np(mesh, a, tr)[..., :3, 3]
    return x[0] if one else x


def _euler_xyz(a):
    c, s = np.cos(a), np.sin(a)
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    sx, sy, sz = s[..., 0], s[..., 1], s[..., 2]
    rows = [
        [cy * cz, -cy * sz, sy],
        [cx * sz + sx * sy * cz, cx * cz - sx * sy * sz, -sx * cy],
        [sx * sz - cx * sy * cz, sx * cz + cx * sy * sz, cx * cy],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def _matrix_to_xyz(r):
    """XYZ Euler angles of ``R = R_x R_y R_z`` (the IK pose's convention)."""
    sy = np.clip(r[..., 0, 2], -1.0, 1.0)
    ay = np.arcsin(sy)
    ax = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    az = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return np.stack([ax, ay, az], -1)


def _joint_model(mesh, joints: np.ndarray, length_scale: float):
    """An `IKModel` whose markers are the origins of ``joints`` (weight 1 on the joint,
    zero bind-local offset): a copy of ``mesh`` with one degenerate triangle per joint at
    its bind position."""
    import dataclasses

    ib = np.asarray(mesh.inverse_bind, np.float64)
    verts = np.linalg.inv(ib)[:, :3, 3]  # bind-pose joint origins: B_j⁻¹ maps them to 0
    nj = mesh.num_joints
    sj = np.zeros((nj, 4), np.int32)
    sj[:, 0] = np.arange(nj)
    sw = np.zeros((nj, 4))
    sw[:, 0] = 1.0
    faces = np.repeat(np.arange(nj, dtype=np.int32)[:, None], 3, axis=1)
    pts = dataclasses.replace(mesh, vertices=verts, faces=faces, skin_joints=sj, skin_weights=sw)
    bary = np.zeros((len(joints), 3))
    bary[:, 0] = 1.0
    ms = MarkerSet(jnp.asarray(np.asarray(joints, np.int32)), jnp.asarray(bary))
    model = ik_model(pts, ms)
    return model._replace(length_scale=jnp.asarray(length_scale, model.length_scale.dtype))


# ----------------------------------------------------------------------------- helpers


def _path_length(parents, x, a: int, b: int) -> float:
    """Length of the skeleton's path between joints ``a`` and ``b`` (rest positions ``x``)."""

    def chain(j):
        out = [int(j)]
        while parents[out[-1]] >= 0:
            out.append(int(parents[out[-1]]))
        return out

    ca, cb = chain(a), chain(b)
    common = next(j for j in ca if j in cb)
    n = 0.0
    for c in (ca, cb):
        for j in c[: c.index(common)]:
            n += float(np.linalg.norm(x[j] - x[parents[j]]))
    return n


def _align(bc: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """The rotation ``Q`` best taking the character's bone vectors ``bc`` (rows) onto the
    source's ``bs`` (`fxspace.rigid.fit_rotation`; one bone, or bones on one line: the
    shortest arc)."""
    if len(bc) >= 2:
        Q, sv = fit_rotation(np.asarray(bc, np.float64), np.asarray(bs, np.float64))
        # sv of the mean Σ bs bcᵀ / n: the unnormalised test sv₁ > 1e-6 max(sv₀, 1e-12)
        if sv[1] > 1e-6 * max(sv[0], 1e-12 / len(bc)):
            return Q
    a = bc.sum(0)
    b = bs.sum(0)
    a, b = a / (np.linalg.norm(a) or 1.0), b / (np.linalg.norm(b) or 1.0)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: a half turn about any axis orthogonal to a
        ax = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        ax /= np.linalg.norm(ax)
        return 2 * np.outer(ax, ax) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def _rotation_copy(mesh, g_rest, r_src, si, ci, x_rest, tgt, finite) -> Pose:
    """Plain rotation copying through the rest poses: a corresponded character joint
    takes its source joint's world rotation, ``R_c(t) = R_s(t) Q R_c,rest``, where ``Q``
    turns the character's rest bones (to its corresponded children) onto the source's
    rest bones (a Motion's rest has identity rotations); the other joints keep their rest
    local rotation; the hips (the corresponded joint nearest the root) on the scaled
    source."""
    t = r_src.shape[0]
    nj = mesh.num_joints
    par = np.asarray(mesh.parents)
    s = np.asarray(mesh.rest_scales, np.float64)
    lin = g_rest[:, :3, :3]
    rot_rest_g = lin / np.cbrt(np.abs(np.linalg.det(lin)))[:, None, None]
    c_rest = g_rest[:, :3, 3]
    pos = {int(c): k for k, c in enumerate(ci)}

    def corr_parent(j):
        p = par[j]
        while p >= 0 and int(p) not in pos:
            p = par[p]
        return int(p)

    q = {}
    for c in sorted(pos, key=lambda j: len(_chain(par, j))):
        kids = [d for d in pos if corr_parent(d) == c]
        if kids:
            bc = np.array([c_rest[d] - c_rest[c] for d in kids])
            bs = np.array([x_rest[pos[d]] - x_rest[pos[c]] for d in kids])
            q[c] = _align(bc, bs)
        else:
            p = corr_parent(c)
            q[c] = q.get(p, np.eye(3))
    rw = np.empty((t, nj, 3, 3))
    angles = np.zeros((t, nj, 3))
    _, loc = _char_rest(mesh)
    rr = loc[:, :3, :3] / s[:, None, :]
    for j in range(nj):
        if j in pos:
            rw[:, j] = r_src[:, si[pos[j]]] @ q[j] @ rot_rest_g[j]
        elif par[j] < 0:
            rw[:, j] = rot_rest_g[j]
        else:
            rw[:, j] = rw[:, par[j]] @ rr[j]
        if par[j] < 0:
            b = np.asarray(mesh.base_transforms[j])[:3, :3]
            b = b / np.cbrt(abs(np.linalg.det(b)))
            local = b.T @ rw[:, j]
        else:
            local = np.swapaxes(rw[:, par[j]], -1, -2) @ rw[:, j]
        angles[:, j] = _matrix_to_xyz(rr[j].T @ local)
    angles = np.where(finite[:, None, None], angles, 0.0)
    # the world translation putting the corresponded joint nearest the root on its target
    k0 = min(range(len(ci)), key=lambda k: len(_chain(par, ci[k])))
    x0 = _global_frames_np(mesh, angles, np.zeros((t, 3)))[:, ci[k0], :3, 3]
    trans = np.where(finite[:, None], tgt[:, k0] - x0, 0.0)
    return Pose(angles, trans)


def _chain(parents, j):
    out = [int(j)]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out
