"""Upper/lower-body splicing (after Heck, Kovar & Gleicher 2006) and heading utilities."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from fxspace._validate import _is_tracer, as_float_array, check_index, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.rigid import fit_rotation
from fxspace.rotations import (
    _xp,
    matrix_to_quat,
    quat_conj,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
)

if TYPE_CHECKING:
    from fxspace.motion._types import Motion

__all__ = [
    "heading_quat",
    "align_start",
    "upper_body_mask",
    "splice_pose",
    "torso_joints",
    "heck_splice",
]


def _check_quats(q, name: str, shape=None):
    """``q`` as a float quaternion array (..., 4): NumPy stays NumPy (lists become NumPy),
    jax stays jax; NaN kept (NaN out)."""
    xp = "jax" if isinstance(q, jax.Array) else "numpy"
    q = as_float_array(q, name, finite="allow", xp=xp)
    if q.ndim < 1 or q.shape[-1] != 4 or (shape is not None and q.shape != shape):
        want = "(..., 4)" if shape is None else str(shape)
        raise FxspaceError(f"{name} must have shape {want} (quaternions), got {q.shape}")
    return q


def heading_quat(q: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Yaw-only (about +Y) part of a root orientation: the rotation taking +Z to the root's
    forward direction projected on the ground."""
    q = _check_quats(q, "q")
    xp = _xp(q)
    f = quat_rotate(q, xp.broadcast_to(xp.asarray([0.0, 0.0, 1.0], q.dtype), q.shape[:-1] + (3,)))
    yaw = xp.arctan2(f[..., 0], f[..., 2])
    up = xp.broadcast_to(xp.asarray([0.0, 1.0, 0.0], q.dtype), q.shape[:-1] + (3,))
    return quat_from_axis_angle(up, yaw)


@checked
def align_start(motion: Motion, frame: int = 0):
    """A copy of ``motion`` moved on the ground so that at ``frame`` the root is above the
    origin and faces +Z (a rotation about +Y and a horizontal translation; heights kept)."""
    xp = _xp(motion.rotations, motion.root_translation)
    q0 = motion.rotations[frame, 0]
    hinv = quat_conj(heading_quat(q0))
    r0 = motion.root_translation[frame] * xp.asarray([1.0, 0.0, 1.0])
    T = motion.root_translation.shape[0]
    root = quat_rotate(xp.broadcast_to(hinv, (T, 4)), motion.root_translation - r0)
    root_q = quat_mul(xp.broadcast_to(hinv, (T, 4)), motion.rotations[:, 0])
    rot = xp.concatenate([root_q[:, None], motion.rotations[:, 1:]], axis=1)
    return dataclasses.replace(motion, root_translation=root, rotations=rot)


def _check_parents(parents) -> np.ndarray:
    pa = np.asarray(parents) if isinstance(parents, list | tuple | np.ndarray) else None
    if pa is None or pa.ndim != 1 or pa.size == 0 or pa.dtype.kind not in "iu":
        raise FxspaceError(f"parents must be a non-empty sequence of joint indices, got {parents}")
    if np.any(pa < -1) or np.any(pa >= np.arange(len(pa))):
        raise FxspaceError("parents must list each joint's parent before it (-1 for a root)")
    return pa


def upper_body_mask(
    parents: tuple[int, ...], names: tuple[str, ...], spine_root: str = "lowerback"
) -> Bool[Array, " J"]:
    """Joints above the pelvis: ``spine_root`` and all its descendants."""
    _check_parents(parents)
    if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
        raise FxspaceError(f"names must be a sequence of joint names (str), got {names!r}")
    if len(names) != len(parents):
        raise FxspaceError(f"names ({len(names)}) and parents ({len(parents)}) must match")
    if not isinstance(spine_root, str) or spine_root not in names:
        raise FxspaceError(f"spine_root {spine_root!r} is not a joint; joints are {list(names)}")
    s = names.index(spine_root)
    mask = [False] * len(parents)
    for j, p in enumerate(parents):
        mask[j] = j == s or (p >= 0 and mask[p])
    return jnp.asarray(mask)


def _check_mask(mask, J: int):
    if _is_tracer(mask):
        return mask
    m = np.asarray(mask) if not isinstance(mask, str | bytes) and mask is not None else None
    if m is None or m.dtype.kind != "b" or m.shape != (J,):
        what = "None" if m is None else f"{m.dtype} of shape {m.shape}"
        raise FxspaceError(f"mask must be a boolean ({J},) joint mask (upper_body_mask): {what}")
    return mask


def splice_pose(
    lower_q: Float[Array, "J 4"],
    upper_q: Float[Array, "J 4"],
    mask: Bool[Array, " J"],
    spine_root: int,
    posture_transfer: float | Float[Array, ""] = 1.0,
) -> Float[Array, "J 4"]:
    """Upper body of ``upper_q`` on the lower body of ``lower_q`` (root = joint 0 = pelvis).

    Joints in ``mask`` take the upper frame's local rotations (posture relative to the
    pelvis); the rest, the root included, come from the lower frame. Spatial alignment /
    posture transfer at the pelvis (after Heck, Kovar & Gleicher 2006, "Splicing upper-body
    actions with locomotion"; simplified): the world orientation of the
    upper body's first spine joint is taken *relative to the pelvis heading* (yaw only)
    rather than to the full pelvis rotation, so the upper body keeps its lean with respect
    to the ground and faces where the lower body faces: with ``H`` the heading of a root,
    ``q_spine_world = H_lower ⊗ H_upper⁻¹ ⊗ q_root_upper ⊗ q_spine_upper`` (blended with the
    plain local copy by ``posture_transfer`` ∈ [0, 1], nlerp).
    """
    upper_q = _check_quats(upper_q, "upper_q")
    lower_q = _check_quats(lower_q, "lower_q", shape=upper_q.shape)
    if upper_q.ndim != 2:
        raise FxspaceError(f"upper_q must be (J, 4), got shape {upper_q.shape}")
    mask = jnp.asarray(_check_mask(mask, upper_q.shape[0]))
    if not _is_tracer(spine_root):
        spine_root = check_index(spine_root, "spine_root", upper_q.shape[0])
    if np.ndim(posture_transfer) != 0:
        raise FxspaceError(f"posture_transfer must be a scalar in [0, 1], got {posture_transfer!r}")
    if not _is_tracer(posture_transfer):
        posture_transfer = check_scalar(posture_transfer, "posture_transfer", low=0.0, high=1.0)
    out = jnp.where(mask[:, None], upper_q, lower_q)
    root_l, root_u = lower_q[0], upper_q[0]
    world_u = quat_mul(root_u, upper_q[spine_root])
    target = quat_mul(quat_mul(heading_quat(root_l), quat_conj(heading_quat(root_u))), world_u)
    local_aligned = quat_mul(quat_conj(root_l), target)
    plain = upper_q[spine_root]
    sign = jnp.where(jnp.sum(plain * local_aligned) < 0, -1.0, 1.0)
    q = quat_normalize((1 - posture_transfer) * plain + posture_transfer * sign * local_aligned)
    return out.at[spine_root].set(q)


def torso_joints(parents: tuple[int, ...], mask, spine_root: int) -> tuple[int, ...]:
    """The upper-body joints that carry the torso's orientation (Heck et al.'s "spine and
    shoulders"): the spine chain from ``spine_root`` to the first joint where the torso
    branches (three or more children: neck and both shoulders), and every upper-body joint
    at most two levels below that branch (neck, clavicles, and the shoulders' centres).
    The arms below the shoulders and the hands are not part of it. A skeleton without such a
    branch gives every joint in ``mask``."""
    pa = [int(p) for p in _check_parents(parents)]
    spine_root = check_index(spine_root, "spine_root", len(pa))
    mk = np.asarray(mask) if mask is not None and not isinstance(mask, str | bytes) else None
    if mk is None or mk.dtype.kind != "b" or mk.shape != (len(pa),) or not mk[spine_root]:
        raise FxspaceError(
            f"mask must be a boolean ({len(pa)},) upper-body mask that holds spine_root "
            "(upper_body_mask)"
        )
    m = [bool(b) for b in mk]
    children = [[c for c, p in enumerate(pa) if p == j] for j in range(len(pa))]
    depth = {spine_root: 0}
    for j in range(spine_root + 1, len(pa)):
        if m[j] and pa[j] in depth:
            depth[j] = depth[pa[j]] + 1
    branch = next((j for j in sorted(depth, key=depth.get) if len(children[j]) >= 3), None)
    if branch is None:
        return tuple(sorted(depth))
    return tuple(sorted(j for j, d in depth.items() if d <= depth[branch] + 2))


def _torso_frames(q, parents, offsets, chain, torso):
    """World rotation of each joint of ``chain`` (root → splice joint, root translation 0) and
    the torso joints' positions relative to the splice joint in its own frame, by unrolled
    forward kinematics over those joints only (static ``chain``/``torso``)."""
    R = {}
    for j in chain:
        Rj = quat_to_matrix(q[j])
        R[j] = Rj if parents[j] < 0 else R[parents[j]] @ Rj
    s = chain[-1]
    loc = {s: (jnp.eye(3, dtype=q.dtype), jnp.zeros(3, q.dtype))}
    for j in torso:
        if j == s:
            continue
        Rp, pp = loc[parents[j]]
        loc[j] = (Rp @ quat_to_matrix(q[j]), pp + Rp @ offsets[j])
    return R, jnp.stack([loc[j][1] for j in torso])


def _shortest_arc(a, b, amount):
    """``amount`` ∈ [0, 1] of the smallest rotation (matrix) taking direction ``a`` to ``b``."""
    a = a / jnp.linalg.norm(a)
    b = b / jnp.linalg.norm(b)
    axis = jnp.cross(a, b)
    s = jnp.linalg.norm(axis)
    angle = jnp.arctan2(s, jnp.dot(a, b)) * amount
    k = axis / jnp.where(s > 1e-12, s, 1.0)
    K = jnp.asarray([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], a.dtype)
    K = K * (s > 1e-12)
    return jnp.eye(3, dtype=a.dtype) + jnp.sin(angle) * K + (1 - jnp.cos(angle)) * (K @ K)


def heck_splice(
    lower_q: Float[Array, "J 4"],
    upper_q: Float[Array, "J 4"],
    parents: tuple[int, ...],
    offsets: Float[Array, "J 3"],
    mask: Bool[Array, " J"],
    spine_root: int,
    torso: tuple[int, ...],
    posture_transfer: float | Float[Array, ""] = 1.0,
) -> Float[Array, "J 4"]:
    """Upper body of ``upper_q`` on the lower body of ``lower_q`` in Heck, Kovar & Gleicher's
    two stages (2006, "Splicing upper-body actions with locomotion"; the stages Ha & Han §3
    name: *spatial alignment* then *posture transfer*, a rotation at the splice joint per
    frame). Temporal alignment, their first step, is Ha & Han's clock alignment (eqs. 1–3).

    1. **Spatial alignment**: the upper body is rotated rigidly at ``spine_root`` so that its
       torso points (`torso_joints`: spine, neck, shoulders) best match, in the least-squares
       sense (Horn's closed form about the splice joint), the torso of the locomotion frame
       ``lower_q``: the spliced torso takes the locomotion's secondary motion (the shoulders'
       counter-swing, the bob and sway that go with the legs) while the arms keep their
       pose relative to the torso.
    2. **Posture transfer**: the action's overall posture is given back: the torso's long
       axis is tilted (smallest rotation) to where it points in the action frame
       ``upper_q``, relative to the ground and the heading (a forward lean stays a forward
       lean); ``posture_transfer`` ∈ [0, 1] is the fraction of that tilt applied (0: the
       locomotion's torso, as after step 1).

    Both rotations depend on the action frame *and* the locomotion frame, so a new lower
    body moves every upper sample differently — the problem of Ha & Han's Fig. 2 that the
    §3.2 re-placement approximates. Root = joint 0; joints in ``mask`` take the upper
    frame's local rotations, the rest the lower frame's; ``parents``/``torso`` static.
    """
    upper_q = _check_quats(upper_q, "upper_q")
    lower_q = _check_quats(lower_q, "lower_q", shape=upper_q.shape)
    if upper_q.ndim != 2:
        raise FxspaceError(f"upper_q must be (J, 4), got shape {upper_q.shape}")
    J = upper_q.shape[0]
    mask = jnp.asarray(_check_mask(mask, J))
    spine_root = check_index(spine_root, "spine_root", J)
    torso = tuple(int(t) for t in torso)
    if len(torso) < 3 or not all(0 <= t < J for t in torso):
        raise FxspaceError(
            f"torso must list at least 3 of the {J} joints (torso_joints), got {torso}"
        )
    if np.ndim(posture_transfer) != 0:
        raise FxspaceError(f"posture_transfer must be a scalar in [0, 1], got {posture_transfer!r}")
    if not _is_tracer(posture_transfer):
        posture_transfer = check_scalar(posture_transfer, "posture_transfer", low=0.0, high=1.0)
    offsets = jnp.asarray(offsets, upper_q.dtype)
    s = spine_root
    chain = [s]
    while parents[chain[-1]] >= 0:
        chain.append(parents[chain[-1]])
    chain = chain[::-1]  # root → … → splice joint
    seen = {s}
    for j in torso:  # the torso hangs below the splice joint, parents first
        if j != s and parents[j] not in seen:
            raise FxspaceError(f"torso joint {j} must hang below spine_root {s} (torso_joints)")
        seen.add(j)
    RL, dL = _torso_frames(lower_q, parents, offsets, chain, torso)
    RU, src = _torso_frames(upper_q, parents, offsets, chain, torso)
    dst = dL @ RL[s].T  # the locomotion's torso (world, relative to the splice joint)
    W1 = fit_rotation(src, dst).rotation  # step 1: the splice joint's world rotation
    up = jnp.mean(src, axis=0)  # the torso's long axis (splice-joint frame)
    H = quat_to_matrix(quat_mul(heading_quat(lower_q[0]), quat_conj(heading_quat(upper_q[0]))))
    W = _shortest_arc(W1 @ up, H @ RU[s] @ up, posture_transfer) @ W1  # step 2
    parent = parents[s]
    local = W if parent < 0 else RL[parent].T @ W
    out = jnp.where(mask[:, None], upper_q, lower_q)
    q = matrix_to_quat(local)
    q = jnp.where(jnp.sum(q * upper_q[s]) < 0, -q, q)
    return out.at[s].set(quat_normalize(q))
