"""Optional regularisers for mesh IK (the older interface to `fxspace.mesh.IKConstraints`).

`ik_regularization` keeps working: `constraints_from_regularization` turns an
`IKRegularization` into the equivalent constraint blocks (the same objective), which
`fxspace.solve_ik` takes as ``constraints=``, so every solver, LM included, takes all
three terms.

Park, Kang & Kwon (§6, future work) note that positional constraints alone give unnatural
poses with few markers and name normal constraints among the remedies. Three terms can be
added to the paper's objective ``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` (eq. (1)), each with its own
weight (zero = off); with ``L`` the model's ``length_scale`` (so the weights are free of
the mesh's units):

- **joint-angle prior**: ``w_p L² Σ_ad (θ_ad − θ̄_ad)²`` towards the rest pose
  (``θ̄ = 0``) or the previous frame (``θ̄`` = the solver's initial pose);
- **joint limits**: ``w_l L² Σ_ad (max(0, θ_ad − hi_ad)² + max(0, lo_ad − θ_ad)²)``, a
  quadratic penalty outside ``[lo, hi]`` per Euler angle;
- **normal constraint**: ``w_n L² Σ_k ‖n̂_k(θ) − n̂*_k‖²``, the unit normal of each
  marker's posed triangle against a target normal (the triangle corners are skinned points
  too: a second `IKModel` on the corners gives them, and the term's gradient is
  taken by ``jax.grad``; the positional term keeps the chosen gradient form).

The prior and the limits have closed-form gradients and Gauss–Newton Hessians (diagonal);
the normal term's Jacobian is taken by forward-mode autodiff (Levenberg–Marquardt) or its
gradient by ``jax.grad`` (BFGS, Adam).

Example:

```python
reg = fx.mesh.ik_regularization(model, prior=1e-3, prior_to="previous", limits=1.0,
                                 limit=np.pi / 2)
cons = fx.mesh.constraints_from_regularization(reg)
res = fx.solve_ik(model, targets, init=prev, constraints=cons)
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.mesh._ik_constraints import (
    IKConstraints,
    JointLimits,
    JointPrior,
    NormalConstraint,
    marker_normals,
)
from fxspace.mesh._ik_model import IKModel, ik_model
from fxspace.mesh._markers import MarkerSet
from fxspace.mesh._skinning import Pose

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import SkinnedMesh

__all__ = [
    "IKRegularization",
    "ik_regularization",
    "regularization_value_and_gradient",
    "marker_normals",
    "constraints_from_regularization",
]


class IKRegularization(NamedTuple):
    """Weights and data of the optional IK regularisers (a pytree of arrays; build it with
    `ik_regularization`)."""

    prior: Float[Array, ""]  # w_p
    prior_previous: Float[Array, ""]  # 1: towards the initial pose (previous frame), 0: rest
    limits: Float[Array, ""]  # w_l
    lower: Float[Array, "joints 3"]
    upper: Float[Array, "joints 3"]
    normal: Float[Array, ""]  # w_n
    corners: IKModel | None  # the markers' triangle corners (3K "markers"), for the normals


@checked
def ik_regularization(
    model: IKModel,
    *,
    prior: float = 0.0,
    prior_to: Literal["rest", "previous"] = "rest",
    limits: float = 0.0,
    limit: float | tuple[np.ndarray, np.ndarray] = np.pi / 2,
    normal: float = 0.0,
    mesh: SkinnedMesh | None = None,
    markers: MarkerSet | None = None,
) -> IKRegularization:
    """Build the regularisers' weights and data for `fxspace.solve_ik`.

    **Arguments:**

    - `model`: the `IKModel` they will be used with.
    - `prior`: weight ``w_p`` of the joint-angle prior (0 = off).
    - `prior_to`: ``"rest"`` (``θ̄ = 0``) or ``"previous"`` (``θ̄`` = the initial pose).
    - `limits`: weight ``w_l`` of the joint-limit penalty (0 = off).
    - `limit`: a symmetric bound in radians for every Euler angle, or ``(lower, upper)``
      arrays of shape ``(J, 3)``.
    - `normal`: weight ``w_n`` of the normal constraint (0 = off; then `mesh` and
      `markers` are needed, and `fxspace.solve_ik` needs ``target_normals``).

    **Returns:** an `IKRegularization`.
    """
    nj = model.ancestors.shape[0]
    dt = model.local_rest.dtype
    for name, w in (("prior", prior), ("limits", limits), ("normal", normal)):
        if not np.isfinite(w) or w < 0:
            raise FxspaceError(f"regularisation weight {name} must be finite and >= 0, got {w}")
    if prior_to not in ("rest", "previous"):
        raise FxspaceError(f"prior_to must be 'rest' or 'previous', got {prior_to!r}")
    if isinstance(limit, tuple):
        lo, hi = (np.broadcast_to(np.asarray(a, np.float64), (nj, 3)) for a in limit)
    else:
        if not np.isfinite(limit) or limit <= 0:
            raise FxspaceError(f"limit must be a positive angle in radians, got {limit}")
        lo, hi = np.full((nj, 3), -float(limit)), np.full((nj, 3), float(limit))
    if np.any(lo > hi):
        raise FxspaceError("joint limits need lower <= upper for every angle")
    corners = None
    if normal > 0:
        if mesh is None or markers is None:
            raise FxspaceError("the normal constraint needs the mesh and the markers")
        k = int(np.asarray(markers.triangles).shape[0])
        eye = np.repeat(np.eye(3), k, axis=0)  # corner m of every marker, m-major
        ms = MarkerSet(jnp.tile(jnp.asarray(markers.triangles), 3), jnp.asarray(eye))
        corners = ik_model(mesh, ms, dtype=dt)
    a = lambda x: jnp.asarray(x, dtype=dt)
    return IKRegularization(
        a(prior),
        a(1.0 if prior_to == "previous" else 0.0),
        a(limits),
        a(lo),
        a(hi),
        a(normal),
        corners,
    )


def _normal_term(corners: IKModel, pose: Pose, target_normals: Array) -> Array:
    d = marker_normals(corners, pose) - target_normals
    return jnp.sum(d * d)


def regularization_value_and_gradient(
    reg: IKRegularization,
    length_scale: Array,
    pose: Pose,
    init: Pose,
    target_normals: Float[Array, "markers 3"] | None,
) -> tuple[Array, Pose, Array]:
    """Value, gradient and the diagonal of the (half) Gauss–Newton Hessian of the angle
    terms (prior + limits; the normal term has none here).

    **Returns:** ``(R, ∇R, h)`` with ``h`` of shape ``(J, 3)`` (angles only).
    """
    l2 = length_scale**2
    ref = reg.prior_previous * init.angles
    dth = pose.angles - ref
    over = jnp.maximum(pose.angles - reg.upper, 0.0) - jnp.maximum(reg.lower - pose.angles, 0.0)
    active = (over != 0).astype(pose.angles.dtype)
    val = l2 * (reg.prior * jnp.sum(dth * dth) + reg.limits * jnp.sum(over * over))
    g_ang = 2.0 * l2 * (reg.prior * dth + reg.limits * over)
    grad = Pose(g_ang, jnp.zeros_like(pose.translation))
    if reg.corners is not None and target_normals is not None:
        vn, gn = jax.value_and_grad(_normal_term, argnums=1)(reg.corners, pose, target_normals)
        val = val + l2 * reg.normal * vn
        grad = jax.tree_util.tree_map(lambda a, b: a + l2 * reg.normal * b, grad, gn)
    hdiag = l2 * (reg.prior + reg.limits * active)
    return val, grad, hdiag


@checked
def constraints_from_regularization(reg: IKRegularization) -> IKConstraints:
    """The same terms as `IKConstraints` (the objective is identical): the prior and the
    limits as residual blocks, the normal term on every marker."""
    nk = reg.corners.marker_joints.shape[0] // 3 if reg.corners is not None else 0
    normal = None
    if reg.corners is not None:
        normal = NormalConstraint(reg.corners, jnp.arange(nk, dtype=jnp.int32), reg.normal)
    return IKConstraints(
        marker_weights=None,
        normal=normal,
        contact=None,
        limits=JointLimits(reg.lower, reg.upper, reg.limits),
        prior=JointPrior(reg.prior, reg.prior_previous),
    )
