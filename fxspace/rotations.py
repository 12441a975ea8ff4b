"""The one home of rotations: unit quaternions, rotation matrices and Euler angles.

Quaternions are ``(w, x, y, z)`` (Hamilton product, active rotations) unless a function's
``order`` argument says ``"xyzw"`` (glTF's and scipy's component order); convert with
`quat_xyzw_to_wxyz` / `quat_wxyz_to_xyzw`. Every function accepts numpy arrays
(computed in numpy, no compilation: readers and writers use this) or JAX arrays (jit,
vmap and grad work).

Euler angles follow the BVH / Acclaim convention: a sequence of axes ``"ZYX"`` with
angles ``(a0, a1, a2)`` means ``R = R_Z(a0) @ R_Y(a1) @ R_X(a2)`` (intrinsic rotations in
the listed order; the last-listed axis is applied to the vector first).
"""

from __future__ import annotations

from typing import Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import check_scalar, checked
from fxspace.errors import FxspaceError

__all__ = [
    "quat_mul",
    "quat_conj",
    "quat_rotate",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_from_axis_angle",
    "euler_to_quat",
    "quat_to_euler",
    "quat_normalize",
    "quat_slerp",
    "quat_nlerp",
    "quat_xyzw_to_wxyz",
    "quat_wxyz_to_xyzw",
    "euler_to_matrix",
    "QuatOrder",
]

QuatOrder = Literal["wxyz", "xyzw"]

_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _xp(*arrays):
    """numpy for numpy inputs (readers/writers: no compilation), jax.numpy otherwise."""
    return np if all(isinstance(a, np.ndarray | np.generic | float) for a in arrays) else jnp


@checked
def quat_mul(p: Float[Array, "... 4"], q: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Hamilton product ``p ⊗ q`` (rotate by ``q`` first, then by ``p``)."""
    pw, px, py, pz = (p[..., i] for i in range(4))
    qw, qx, qy, qz = (q[..., i] for i in range(4))
    return _xp(p, q).stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


@checked
def quat_conj(q: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Conjugate (the inverse of a unit quaternion)."""
    if np.ndim(q) < 1 or np.shape(q)[-1] != 4:
        raise FxspaceError(f"q must be (..., 4) quaternions (w, x, y, z), got shape {np.shape(q)}")
    return q * _xp(q).asarray([1.0, -1.0, -1.0, -1.0], dtype=q.dtype).reshape(
        (1,) * (q.ndim - 1) + (4,)
    )


@checked
def quat_normalize(q: Float[Array, "... 4"], eps: float = 1e-12) -> Float[Array, "... 4"]:
    """``q / ‖q‖`` along the last axis (4 components).

    A quaternion whose norm is below ``eps`` (e.g. the zero quaternion) is divided by
    ``eps`` instead, so it stays (near) zero rather than becoming NaN; ``eps`` must be
    > 0. NaN components give NaN."""
    eps = check_scalar(eps, "eps", low=0.0, low_open=True)
    if np.ndim(q) < 1 or np.shape(q)[-1] != 4:
        raise FxspaceError(f"q must have shape (..., 4), got shape {tuple(np.shape(q))}")
    xp = _xp(q)
    return q / xp.maximum(xp.linalg.norm(q, axis=-1, keepdims=True), eps)


@checked
def quat_xyzw_to_wxyz(q: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Reorder quaternion components from ``(x, y, z, w)`` (glTF, scipy) to ``(w, x, y, z)``."""
    return _xp(q).concatenate([q[..., 3:], q[..., :3]], axis=-1)


@checked
def quat_wxyz_to_xyzw(q: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Reorder quaternion components from ``(w, x, y, z)`` to ``(x, y, z, w)`` (glTF, scipy)."""
    return _xp(q).concatenate([q[..., 1:], q[..., :1]], axis=-1)


@checked
def quat_to_matrix(q: Float[Array, "... 4"], order: QuatOrder = "wxyz") -> Float[Array, "... 3 3"]:
    """Rotation matrix of a unit quaternion whose components are in ``order``."""
    xp = _xp(q)
    if order == "xyzw":
        q = quat_xyzw_to_wxyz(q)
    elif order != "wxyz":
        raise FxspaceError(f"order must be 'wxyz' or 'xyzw', got {order!r}")
    w, x, y, z = (q[..., i] for i in range(4))
    r = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return xp.stack([xp.stack(row, axis=-1) for row in r], axis=-2)


@checked
def matrix_to_quat(R: Float[Array, "... 3 3"], order: QuatOrder = "wxyz") -> Float[Array, "... 4"]:
    """Unit quaternion (``w >= 0``) of a rotation matrix (Shepperd's branch-free variant),
    components in ``order``."""
    if order not in ("wxyz", "xyzw"):
        raise FxspaceError(f"order must be 'wxyz' or 'xyzw', got {order!r}")
    jnp = _xp(R)  # noqa: F811 - numpy for numpy input
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    cands = jnp.stack(
        [
            jnp.stack(
                [
                    1 + m00 + m11 + m22,
                    R[..., 2, 1] - R[..., 1, 2],
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 1, 0] - R[..., 0, 1],
                ],
                -1,
            ),
            jnp.stack(
                [
                    R[..., 2, 1] - R[..., 1, 2],
                    1 + m00 - m11 - m22,
                    R[..., 0, 1] + R[..., 1, 0],
                    R[..., 0, 2] + R[..., 2, 0],
                ],
                -1,
            ),
            jnp.stack(
                [
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 0, 1] + R[..., 1, 0],
                    1 - m00 + m11 - m22,
                    R[..., 1, 2] + R[..., 2, 1],
                ],
                -1,
            ),
            jnp.stack(
                [
                    R[..., 1, 0] - R[..., 0, 1],
                    R[..., 0, 2] + R[..., 2, 0],
                    R[..., 1, 2] + R[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )  # (..., 4, 4): row k is 4 q_k q
    diag = jnp.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    k = jnp.argmax(diag, axis=-1)
    q = jnp.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(q)
    q = q * jnp.where(q[..., :1] < 0, -1.0, 1.0)
    return quat_wxyz_to_xyzw(q) if order == "xyzw" else q


@checked
def quat_rotate(q: Float[Array, "... 4"], v: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Rotate vectors ``v`` by unit quaternions ``q``."""
    xp = _xp(q, v)
    u = q[..., 1:]
    w = q[..., :1]
    t = 2.0 * xp.cross(u, v)
    return v + w * t + xp.cross(u, t)


@checked
def quat_from_axis_angle(
    axis: Float[Array, "... 3"], angle: Float[Array, " ..."]
) -> Float[Array, "... 4"]:
    """Quaternion of a rotation by ``angle`` (radians) about the unit vector ``axis``."""
    if np.ndim(axis) < 1 or np.shape(axis)[-1] != 3:
        raise FxspaceError(f"axis must be (..., 3) unit vectors, got shape {np.shape(axis)}")
    xp = _xp(axis, angle)
    half = 0.5 * angle[..., None]
    shape = xp.broadcast_shapes(half.shape[:-1], axis.shape[:-1])
    half = xp.broadcast_to(half, shape + (1,))
    axis = xp.broadcast_to(axis, shape + (3,))
    return xp.concatenate([xp.cos(half), xp.sin(half) * axis], axis=-1)


def _axis_quat(ax: str, angle: Float[Array, " ..."]) -> Float[Array, "... 4"]:
    e = np.zeros(3, dtype=angle.dtype)
    e[_AXIS[ax]] = 1.0
    return quat_from_axis_angle(e if _xp(angle) is np else jnp.asarray(e), angle)


@checked
def euler_to_quat(
    angles: Float[Array, "... k"], order: str, degrees: bool = True
) -> Float[Array, "... 4"]:
    """Quaternion of ``R = R_{order[0]}(a0) @ R_{order[1]}(a1) @ ...`` (any number of axes)."""
    order = order.upper()
    if any(c not in _AXIS for c in order) or angles.shape[-1] != len(order):
        raise FxspaceError(
            f"order must be a string of X/Y/Z matching angles' last axis, got {order!r} "
            f"for angles of shape {angles.shape}"
        )
    xp = _xp(angles)
    a = xp.deg2rad(angles) if degrees else angles
    q = xp.broadcast_to(xp.asarray([1.0, 0.0, 0.0, 0.0], dtype=a.dtype), a.shape[:-1] + (4,))
    for i, ax in enumerate(order):
        q = quat_mul(q, _axis_quat(ax, a[..., i]))
    return q


@checked
def quat_to_euler(
    q: Float[Array, "... 4"], order: str, degrees: bool = True
) -> Float[Array, "... 3"]:
    """Euler angles in ``order`` (three distinct axes) with ``R = R_a(t0) R_b(t1) R_c(t2)``;
    the middle angle lies in ``[-90°, 90°]``. Inverse of `euler_to_quat`."""
    order = order.upper()
    if len(order) != 3 or len(set(order)) != 3 or any(c not in _AXIS for c in order):
        raise FxspaceError(f"order must be three distinct axes of X/Y/Z, got {order!r}")
    i, j, k = (_AXIS[c] for c in order)
    e = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    xp = _xp(q)
    R = quat_to_matrix(q)
    t1 = xp.arcsin(xp.clip(e * R[..., i, k], -1.0, 1.0))
    t0 = xp.arctan2(-e * R[..., j, k], R[..., k, k])
    t2 = xp.arctan2(-e * R[..., i, j], R[..., i, i])
    out = xp.stack([t0, t1, t2], axis=-1)
    return xp.rad2deg(out) if degrees else out


def _check_lerp(q0, q1, s) -> None:
    """``q0``, ``q1`` (..., 4) and ``s`` (...) must broadcast together."""
    shapes = [np.shape(q0), np.shape(q1)]
    if any(len(sh) < 1 or sh[-1] != 4 for sh in shapes):
        raise FxspaceError(f"q0 and q1 must have shape (..., 4), got {shapes[0]} and {shapes[1]}")
    try:
        np.broadcast_shapes(shapes[0][:-1], shapes[1][:-1], np.shape(s))
    except ValueError:
        raise FxspaceError(
            f"q0 {shapes[0]}, q1 {shapes[1]} and s {np.shape(s)} must broadcast together "
            "(s has the leading shape of the quaternions)"
        ) from None


@checked
def quat_nlerp(
    q0: Float[Array, "... 4"], q1: Float[Array, "... 4"], s: Float[Array, " ..."]
) -> Float[Array, "... 4"]:
    """Normalised linear interpolation along the shorter arc (any component order)."""
    _check_lerp(q0, q1, s)
    jnp = _xp(q0, q1, s)  # noqa: F811
    sign = jnp.where(jnp.sum(q0 * q1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    s = s[..., None]
    return quat_normalize((1 - s) * q0 + s * sign * q1)


@checked
def quat_slerp(
    q0: Float[Array, "... 4"], q1: Float[Array, "... 4"], s: Float[Array, " ..."]
) -> Float[Array, "... 4"]:
    """Spherical linear interpolation along the shorter arc (nlerp where the arc is tiny);
    any component order, as long as ``q0`` and ``q1`` share it."""
    _check_lerp(q0, q1, s)
    jnp = _xp(q0, q1, s)  # noqa: F811
    d = jnp.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = jnp.where(d < 0, -q1, q1)
    d = jnp.abs(d)
    theta = jnp.arccos(jnp.clip(d, -1.0, 1.0))
    small = theta < 1e-6
    st = jnp.where(small, 1.0, jnp.sin(theta))
    s = s[..., None]
    a = jnp.where(small, 1 - s, jnp.sin((1 - s) * theta) / st)
    b = jnp.where(small, s, jnp.sin(s * theta) / st)
    return quat_normalize(a * q0 + b * q1)


def _rot_axis(theta: Float[Array, " ..."], axis: int) -> Float[Array, "... 3 3"]:
    xp = _xp(theta)
    c, s = xp.cos(theta), xp.sin(theta)
    o, z = xp.ones_like(theta), xp.zeros_like(theta)
    if axis == 0:
        rows = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == 1:
        rows = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        rows = [[c, -s, z], [s, c, z], [z, z, o]]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


@checked
def euler_to_matrix(
    angles: Float[Array, "... 3"], order: str = "XYZ", degrees: bool = False
) -> Float[Array, "... 3 3"]:
    """``R = R_{order[0]}(a0) @ R_{order[1]}(a1) @ R_{order[2]}(a2)`` (intrinsic rotations,
    scipy's upper-case sequences); radians unless ``degrees``."""
    order = order.upper()
    if len(order) != 3 or any(c not in _AXIS for c in order):
        raise FxspaceError(f"order must be three axes of X/Y/Z, got {order!r}")
    xp = _xp(angles)
    a = xp.deg2rad(angles) if degrees else angles
    R = _rot_axis(a[..., 0], _AXIS[order[0]])
    for i in (1, 2):
        R = R @ _rot_axis(a[..., i], _AXIS[order[i]])
    return R
