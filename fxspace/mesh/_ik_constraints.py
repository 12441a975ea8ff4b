"""Constraints for mesh IK as weighted residuals, taken by every solver (LM, BFGS, Adam,
optimistix).

Park, Kang & Kwon fit marker positions only (eq. (1)) and name other constraints as
future work (§6). Here each constraint is a block of residuals ``r_c(θ)`` with a weight,
and every solver minimises

    F(θ) = Σ_k w_k ‖p_k(θ) − t_k‖² + Σ_c ‖r_c(θ)‖²,

so Levenberg–Marquardt gets each block's Jacobian (Gauss–Newton ``JᵀJ``, ``Jᵀr``) and the
gradient solvers its gradient ``2 Jᵀr``. With ``L`` the model's ``length_scale`` (the
weights are free of the mesh's units):

- **marker positions**: per-marker weights ``w_k`` (default 1; 0 frees a marker, e.g.
  one held by a contact only);
- **surface normals at markers** (`normal_constraint`): ``√w_n L (n̂_k(θ) − n̂*_k)``, the
  unit normal of each chosen marker's posed triangle against a target normal; the
  triangle corners are skinned points too (a second `IKModel` on the corners), the
  block's Jacobian is taken by forward-mode autodiff (``3 K_n`` rows);
- **point-on-plane contact** (`plane_contact`): ``√w_c (n_c · p_k(θ) − d_c)`` for the
  chosen markers (a foot marker on the floor ``y = 0``: ``n_c = e_y``, ``d_c = 0``). Its
  Jacobian row is ``n_cᵀ J_k`` with ``(J_kᵀ n)_ad = ω_ad · (P_ka × n)`` (the lever arms of
  the factored form), and its gradient folds into the factored gradient: ``δ_k`` becomes
  ``w_k δ_k + w_c c_k n_c``, one eq. (13) pass for both;
- **joint limits** (`joint_limits`): ``√w_l L max(0, θ − hi, lo − θ)`` per Euler angle
  (a hinge residual: Gauss–Newton on the active set);
- **joint-angle prior** (`joint_prior`): ``√w_p L (θ − θ̄)`` towards the rest pose
  (``θ̄ = 0``) or the previous frame (``θ̄`` = the solver's initial pose).

`IKConstraints` gathers them (a pytree; a block that is off is ``None``, so the solvers
compile only what is on). Example:

```python
cons = fx.mesh.ik_constraints(
    model,
    contact=fx.mesh.plane_contact(model, [foot], normal=(0, 1, 0), offset=0.0, weight=100.0),
    normal=fx.mesh.normal_constraint(mesh, markers, weight=0.1),
    limits=fx.mesh.joint_limits(model, np.pi / 2, weight=1.0),
)
res = fx.solve_ik(model, targets, constraints=cons, target_normals=normals)
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import check_choice, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.mesh._ik_gradients import (
    gradient_factored_from_forward,
    gradient_naive_from_forward,
    gram_normal_equations,
)
from fxspace.mesh._ik_model import IKModel, ik_forward, ik_model
from fxspace.mesh._markers import MarkerSet
from fxspace.mesh._skinning import Pose

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import SkinnedMesh

__all__ = [
    "IKConstraints",
    "NormalConstraint",
    "PlaneContact",
    "JointLimits",
    "JointPrior",
    "ik_constraints",
    "normal_constraint",
    "plane_contact",
    "joint_limits",
    "joint_prior",
    "marker_normals",
    "constraint_residuals",
    "constrained_value_and_gradient",
    "constrained_normal_equations",
]


class NormalConstraint(NamedTuple):
    """Surface normals at markers: the corner model of the chosen markers' triangles."""

    corners: IKModel  # 3 K_n skinned corner points, corner m of every marker, m-major
    indices: Int[Array, " kn"]  # which of the model's markers (for reference)
    weight: Float[Array, ""]  # w_n


class PlaneContact(NamedTuple):
    """Point-on-plane contacts, per marker (weight 0: no contact): ``n_k · p_k = d_k``."""

    weights: Float[Array, " markers"]  # w_c per marker
    normals: Float[Array, "markers 3"]  # unit plane normal per marker
    offsets: Float[Array, " markers"]  # d per marker


class JointLimits(NamedTuple):
    """Box limits on the Euler angles, a hinge residual outside ``[lower, upper]``."""

    lower: Float[Array, "joints 3"]
    upper: Float[Array, "joints 3"]
    weight: Float[Array, ""]


class JointPrior(NamedTuple):
    """Joint-angle prior towards the rest pose (``previous = 0``) or the initial pose (1)."""

    weight: Float[Array, ""]
    previous: Float[Array, ""]


class IKConstraints(NamedTuple):
    """Every constraint block of a solve (a pytree; ``None`` = off). Build with
    `ik_constraints`."""

    marker_weights: Float[Array, " markers"] | None = None
    normal: NormalConstraint | None = None
    contact: PlaneContact | None = None
    limits: JointLimits | None = None
    prior: JointPrior | None = None


def _dtype(model: IKModel):
    return model.local_rest.dtype


def _indices(model: IKModel, indices, what: str) -> np.ndarray:
    nk = int(model.marker_joints.shape[0])
    idx = np.atleast_1d(np.asarray(indices))
    if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu":
        raise FxspaceError(f"{what}: marker indices must be a non-empty list of integers")
    if np.any((idx < 0) | (idx >= nk)) or len(np.unique(idx)) != idx.size:
        raise FxspaceError(f"{what}: marker indices must be distinct, in [0, {nk}); got {idx}")
    return idx.astype(np.int64)


@checked
def normal_constraint(
    mesh: SkinnedMesh,
    markers: MarkerSet,
    weight: float = 1.0,
    indices=None,
    dtype=None,
) -> NormalConstraint:
    """The surface-normal constraint at markers ``indices`` (default: all) of ``markers``.

    **Arguments:** `mesh`, `markers`: as given to `ik_model`; `weight`: ``w_n`` (> 0);
    `indices`: which markers carry a normal target (the solve's ``target_normals`` then
    has one row per index, in this order).

    **Returns:** a `NormalConstraint` (its corner model is built here, host side, once).
    """
    w = check_scalar(weight, "weight", low=0.0, low_open=True)
    tri = np.asarray(markers.triangles)
    idx = np.arange(tri.shape[0]) if indices is None else np.atleast_1d(np.asarray(indices))
    if idx.ndim != 1 or idx.size == 0 or np.any((idx < 0) | (idx >= tri.shape[0])):
        raise FxspaceError(f"indices must be marker indices in [0, {tri.shape[0]}), got {idx}")
    k = idx.size
    eye = np.repeat(np.eye(3), k, axis=0)  # corner m of every chosen marker, m-major
    corners = ik_model(mesh, MarkerSet(jnp.asarray(np.tile(tri[idx], 3)), jnp.asarray(eye)), dtype)
    dt = corners.local_rest.dtype
    return NormalConstraint(corners, jnp.asarray(idx, jnp.int32), jnp.asarray(w, dt))


@checked
def plane_contact(
    model: IKModel, indices, normal=(0.0, 1.0, 0.0), offset: float = 0.0, weight: float = 100.0
) -> PlaneContact:
    """Point-on-plane contact for markers ``indices``: ``normal · p_k = offset``.

    **Arguments:** `model`: the `IKModel`; `indices`: the markers on the plane (e.g. a foot
    marker); `normal`: the plane's normal (normalised here; default ``+y``, a floor in a
    y-up scene); `offset`: ``d`` (the floor's height along `normal`); `weight`: ``w_c``
    (> 0; large keeps the marker on the plane while the others are fitted).
    """
    idx = _indices(model, indices, "plane_contact")
    n = np.asarray(normal, np.float64).reshape(-1)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0:
        raise FxspaceError(f"normal must be a finite non-zero 3-vector, got {normal!r}")
    d = check_scalar(offset, "offset")
    w = check_scalar(weight, "weight", low=0.0, low_open=True)
    nk, dt = int(model.marker_joints.shape[0]), _dtype(model)
    ws = np.zeros(nk)
    ws[idx] = w
    return PlaneContact(
        jnp.asarray(ws, dt),
        jnp.asarray(np.tile(n / np.linalg.norm(n), (nk, 1)), dt),
        jnp.full((nk,), d, dt),
    )


@checked
def joint_limits(model: IKModel, limit=np.pi / 2, weight: float = 1.0) -> JointLimits:
    """Joint limits: a symmetric bound (radians) for every Euler angle, or ``(lower,
    upper)`` arrays broadcastable to ``(J, 3)``; `weight` ``w_l`` (> 0)."""
    nj = int(model.ancestors.shape[0])
    if isinstance(limit, tuple):
        lo, hi = (np.broadcast_to(np.asarray(a, np.float64), (nj, 3)) for a in limit)
    else:
        lim = check_scalar(limit, "limit", low=0.0, low_open=True)
        lo, hi = np.full((nj, 3), -lim), np.full((nj, 3), lim)
    if np.any(lo > hi):
        raise FxspaceError("joint limits need lower <= upper for every angle")
    w = check_scalar(weight, "weight", low=0.0, low_open=True)
    a = lambda x: jnp.asarray(x, _dtype(model))
    return JointLimits(a(lo), a(hi), a(w))


@checked
def joint_prior(
    model: IKModel, weight: float, to: Literal["rest", "previous"] = "rest"
) -> JointPrior:
    """Joint-angle prior of weight ``w_p`` (> 0) towards ``"rest"`` or ``"previous"``."""
    w = check_scalar(weight, "weight", low=0.0, low_open=True)
    check_choice(to, "to", ("rest", "previous"))
    a = lambda x: jnp.asarray(x, _dtype(model))
    return JointPrior(a(w), a(1.0 if to == "previous" else 0.0))


@checked
def ik_constraints(
    model: IKModel,
    *,
    marker_weights=None,
    normal: NormalConstraint | None = None,
    contact: PlaneContact | None = None,
    limits: JointLimits | None = None,
    prior: JointPrior | None = None,
) -> IKConstraints:
    """Gather constraint blocks for `fxspace.solve_ik` / `fxspace.track_ik`.

    **Arguments:** `marker_weights`: ``(K,)`` non-negative weights of the positional
    residuals (default: ones); `normal`, `contact`, `limits`, `prior`: blocks from
    `normal_constraint`, `plane_contact`, `joint_limits`, `joint_prior` (``None``: off).
    """
    nk = int(model.marker_joints.shape[0])
    w = None
    if marker_weights is not None:
        w = np.asarray(marker_weights, np.float64)
        if w.shape != (nk,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise FxspaceError(f"marker_weights must be {nk} finite non-negative numbers")
        w = jnp.asarray(w, _dtype(model))
    for name, val, kind in (
        ("normal", normal, NormalConstraint),
        ("contact", contact, PlaneContact),
        ("limits", limits, JointLimits),
        ("prior", prior, JointPrior),
    ):
        if val is not None and not isinstance(val, kind):
            raise FxspaceError(f"{name} must come from fxspace.mesh.{kind.__name__}'s builder")
    return IKConstraints(w, normal, contact, limits, prior)


# ------------------------------------------------------------------------------ residuals


@checked
def marker_normals(corners: IKModel, pose: Pose) -> Float[Array, "markers 3"]:
    """Unit normals of the markers' posed triangles (corners from the corner model)."""
    c = ik_forward(corners, pose).markers
    c = c.reshape(3, -1, 3)
    n = jnp.cross(c[1] - c[0], c[2] - c[0])
    return n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-30)


def _normal_residual(nc: NormalConstraint, scale, pose: Pose, tn: Array) -> Array:
    return (jnp.sqrt(nc.weight) * scale * (marker_normals(nc.corners, pose) - tn)).reshape(-1)


def _angle_residuals(cons: IKConstraints, scale, pose: Pose, init: Pose):
    """Hinge (limits) and prior residuals and their diagonal Jacobians, flattened angles."""
    out = []
    th = pose.angles.reshape(-1)
    if cons.limits is not None:
        lim = cons.limits
        up, lo = lim.upper.reshape(-1), lim.lower.reshape(-1)
        over = jnp.maximum(th - up, 0.0) - jnp.maximum(lo - th, 0.0)
        c = jnp.sqrt(lim.weight) * scale
        out.append((c * over, c * (over != 0).astype(th.dtype)))
    if cons.prior is not None:
        pr = cons.prior
        c = jnp.sqrt(pr.weight) * scale
        out.append((c * (th - pr.previous * init.angles.reshape(-1)), c * jnp.ones_like(th)))
    return out


def _contact_residual(ct: PlaneContact, markers: Array) -> Array:
    return jnp.sum(ct.normals * markers, axis=-1) - ct.offsets


@checked
def constraint_residuals(
    model: IKModel,
    cons: IKConstraints,
    pose: Pose,
    targets: Float[Array, "markers 3"],
    init: Pose,
    target_normals: Array | None,
) -> Float[Array, " m"]:
    """Every residual as one vector (``F(θ) = ‖r‖²``); for optimistix and the tests."""
    p = ik_forward(model, pose).markers
    d = p - targets
    if cons.marker_weights is not None:
        d = jnp.sqrt(cons.marker_weights)[:, None] * d
    parts = [d.reshape(-1)]
    if cons.contact is not None:
        parts.append(jnp.sqrt(cons.contact.weights) * _contact_residual(cons.contact, p))
    if cons.normal is not None:
        parts.append(_normal_residual(cons.normal, model.length_scale, pose, target_normals))
    parts += [r for r, _ in _angle_residuals(cons, model.length_scale, pose, init)]
    return jnp.concatenate(parts)


def _objective(model, cons, pose, targets, init, tn) -> Array:
    r = constraint_residuals(model, cons, pose, targets, init, tn)
    return r @ r


def _flat(pose: Pose) -> Array:
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


@checked
def constrained_value_and_gradient(
    gradient: str,
    model: IKModel,
    cons: IKConstraints,
    pose: Pose,
    targets: Float[Array, "markers 3"],
    init: Pose,
    target_normals: Array | None,
) -> tuple[Array, Pose]:
    """``(F, ∇F)`` with the chosen form (``"factored"`` eq. (13), ``"naive"`` eq. (9),
    ``"autodiff"``) for the marker and contact terms (one pass: the contact folds into
    ``δ``), closed forms for the angle terms, autodiff for the normal term."""
    if gradient == "autodiff":
        return jax.value_and_grad(_objective, argnums=2)(
            model, cons, pose, targets, init, target_normals
        )
    fw = ik_forward(model, pose)
    d = fw.markers - targets
    wd = d if cons.marker_weights is None else cons.marker_weights[:, None] * d
    val = jnp.sum(wd * d)
    if cons.contact is not None:
        c = _contact_residual(cons.contact, fw.markers)
        val = val + jnp.sum(cons.contact.weights * c * c)
        wd = wd + (cons.contact.weights * c)[:, None] * cons.contact.normals
    kernel = gradient_naive_from_forward if gradient == "naive" else gradient_factored_from_forward
    g = kernel(model, fw, wd)
    ga = g.angles.reshape(-1)
    for r, jd in _angle_residuals(cons, model.length_scale, pose, init):
        val = val + r @ r
        ga = ga + 2.0 * jd * r
    g = Pose(ga.reshape(g.angles.shape), g.translation)
    if cons.normal is not None:
        nf = lambda q: jnp.sum(
            _normal_residual(cons.normal, model.length_scale, q, target_normals) ** 2
        )
        vn, gn = jax.value_and_grad(nf)(pose)
        val = val + vn
        g = jax.tree_util.tree_map(jnp.add, g, gn)
    return val, g


@checked
def constrained_normal_equations(
    model: IKModel,
    cons: IKConstraints,
    pose: Pose,
    targets: Float[Array, "markers 3"],
    init: Pose,
    target_normals: Array | None,
) -> tuple[Array, Array, Array]:
    """``(F, Jᵀr, JᵀJ)`` of every residual block (flat pose order), for
    Levenberg–Marquardt."""
    obj, g, h, parts = gram_normal_equations(model, pose, targets, cons.marker_weights)
    if cons.contact is not None:
        ct = cons.contact
        c = _contact_residual(ct, parts.markers)
        # row k: (J_kᵀ n_k)_ad = ω_ad · (P_ka × n_k); translation n_k
        p = jnp.transpose(parts.lever_arms, (2, 0, 1))  # (K, J, 3)
        rows = jnp.einsum("jdc,kjc->kjd", parts.axes, jnp.cross(p, ct.normals[:, None, :]))
        a = jnp.concatenate([rows.reshape(rows.shape[0], -1), ct.normals], axis=1)
        aw = ct.weights[:, None] * a
        g = g + aw.T @ c
        h = h + aw.T @ a
        obj = obj + jnp.sum(ct.weights * c * c)
    nj = pose.angles.shape[0]
    if cons.normal is not None:
        res = lambda x: _normal_residual(
            cons.normal,
            model.length_scale,
            Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :]),
            target_normals,
        )
        x = _flat(pose)
        rn, jn = res(x), jax.jacfwd(res)(x)
        g, h, obj = g + jn.T @ rn, h + jn.T @ jn, obj + rn @ rn
    zero3 = jnp.zeros(3, g.dtype)
    for ra, jd in _angle_residuals(cons, model.length_scale, pose, init):
        g = g + jnp.concatenate([jd * ra, zero3])
        h = h + jnp.diag(jnp.concatenate([jd * jd, zero3]))
        obj = obj + ra @ ra
    return obj, g, h
