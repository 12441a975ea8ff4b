"""The three forms of the IK gradient (Park, Kang & Kwon, §4), the Jacobian and the
normal equations.

Each Euler degree of freedom ``(a, d)`` of joint ``a`` rotates the subtree of ``a``
about the world axis ``ω_ad`` through the joint's world origin ``o_a``, so
``∂p_k/∂θ_ad = Σ_{j ∈ desc(a)} ω_ad × (q_kj − W_kj o_a)`` with ``q_kj = W_kj o_j + L_j u_kj``
the contribution of joint ``j`` to marker ``k``. The gradient has three forms here:

* **naive** (eq. (9)): for every marker ``k``, every joint ``j`` influencing it and every
  ancestor ``a`` of ``j`` (``j`` included), accumulate ``2 ω_ad · ((q_kj − W_kj o_a) × δ_k)``
  — three nested loops, ``O(K · N · D)`` cross products (``N`` joints per marker, ``D``
  the depth). Written vectorised over a ``(K, N, D)`` gather of the ancestor table and a
  segment-sum into the joints: the same arithmetic as the triple loop.
* **factored** (eq. (13)): per joint ``j`` precompute ``s_j = Σ_k W_kj δ_k`` and
  ``c_j = Σ_k q_kj × δ_k`` (one marker × joint pass: a single product of the precomputed
  dense skinning with ``δ``), then accumulate them up the hierarchy,
  ``S_a = Σ_{j ∈ desc(a)} s_j`` and ``C_a`` alike (one joint × ancestor pass: a
  segment-sum over the hierarchy, as a product with the ``(J, J)`` descendant matrix),
  and ``∂E/∂θ_ad = 2 ω_ad · (C_a − o_a × S_a)``: ``O(K · J + J²)``.
* **autodiff**: ``jax.grad`` of `ik_objective`.

All three share the forward pass `fxspace.ik_forward`. The analytic per-marker
Jacobian (`ik_jacobian`) gives `ik_normal_equations`; the Levenberg–Marquardt solver
builds the same normal equations with `gram_normal_equations` (markers minor, one
product for the Gram matrix, few kernels: XLA:CPU pays a launch per kernel).

Example:

```python
g = fx.ik_gradient_factored(model, pose, targets)   # a Pose-shaped gradient
```
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.mesh._ik_model import IKForward, IKModel, ik_forward, ik_frames, ik_objective
from fxspace.mesh._skinning import Pose

__all__ = [
    "GRADIENTS",
    "Gradient",
    "gradient_naive_from_forward",
    "gradient_factored_from_forward",
    "ik_gradient_naive",
    "ik_gradient_factored",
    "ik_gradient_autodiff",
    "value_and_gradient",
    "ik_jacobian",
    "ik_normal_equations",
    "marker_normal_equations",
    "lever_arms",
    "gram_normal_equations",
    "GramParts",
]


class GramParts(NamedTuple):
    """What `gram_normal_equations` computes on the way (for the constraint blocks)."""

    markers: Float[Array, "markers 3"]  # p_k
    lever_arms: Float[Array, "joints 3 markers"]  # P_ka, markers minor
    axes: Float[Array, "joints 3 3"]  # ω_ad, [joint, dof, xyz]


Gradient = Literal["factored", "naive", "autodiff"]
GRADIENTS: tuple[str, ...] = ("factored", "naive", "autodiff")


def _pad(x: Array) -> Array:
    return jnp.concatenate([x, jnp.zeros((1,) + x.shape[1:], x.dtype)], axis=0)


@checked
def gradient_naive_from_forward(
    model: IKModel, fw: IKForward, delta: Float[Array, "markers 3"]
) -> Pose:
    """Eq. (9) from a forward pass: marker × joint × ancestor, ``O(K·N·D)``.

    For every marker ``k``, every joint ``j`` influencing it and every ancestor ``a`` of
    ``j`` (``j`` included): ``2 ω_ad · ((q_kj − W_kj o_a) × δ_k)``, vectorised over a
    ``(K, N, D)`` gather of the ancestor table and segment-summed into the joints; the
    translation gradient is ``2 Σ_k δ_k``.
    """
    nj = model.ancestors.shape[0]
    a = model.ancestors[model.marker_joints]  # (K, N, D): the ancestors of each marker joint
    o_a = _pad(fw.origins)[a]  # (K, N, D, 3)
    w_a = _pad(fw.axes)[a]  # (K, N, D, 3 dof, 3)
    w = model.marker_skin[..., 3]  # W_kn
    r = fw.contributions[:, :, None, :] - w[:, :, None, None] * o_a
    tau = jnp.cross(r, delta[:, None, None, :])  # (K, N, D, 3)
    per_dof = 2.0 * jnp.einsum("kndc,kndec->knde", tau, w_a)  # (K, N, D, 3)
    g = jax.ops.segment_sum(per_dof.reshape(-1, 3), a.reshape(-1), num_segments=nj + 1)
    return Pose(g[:nj], 2.0 * delta.sum(axis=0))


@checked
def gradient_factored_from_forward(
    model: IKModel, fw: IKForward, delta: Float[Array, "markers 3"]
) -> Pose:
    """Eq. (13) from a forward pass: per-joint sums, then up the hierarchy, ``O(K·J + J²)``.

    Marker × joint: one product of the precomputed ``(4J + 1, K)`` dense skinning with
    ``δ`` gives ``s_j = Σ_k W_kj δ_k``, ``M_j = Σ_k u_kj δ_kᵀ`` (the paper's ``Σ δ`` and
    ``Σ (R v)^ δ``) and ``Σ_k δ_k`` (the translation gradient, halved), whence
    ``c_j = Σ_k q_kj × δ_k = o_j × s_j + Σ_c L_j[:, c] × M_j[c, :]``.
    Joint × ancestor: ``S_a = Σ_{j ∈ desc(a)} s_j`` and ``C_a`` alike, a segment-sum over
    the hierarchy written as one product with the ``(J, J)`` descendant matrix. Then
    ``∂E/∂θ_ad = 2 ω_ad · (C_a − o_a × S_a)``.
    """
    nj = fw.origins.shape[0]
    sm = model.skin @ delta  # (4J + 1, 3)
    m = sm[: 3 * nj].reshape(nj, 3, 3)  # M_j[c, d] = Σ_k u_kjc δ_kd
    s = sm[3 * nj : 4 * nj]
    lin, o = fw.linear, fw.origins
    c = jnp.cross(o, s) + sum(jnp.cross(lin[:, :, i], m[:, i, :]) for i in range(3))
    tot = model.descendants @ jnp.concatenate([s, c], axis=1)  # (J, 6): S_a, C_a
    tau = tot[:, 3:] - jnp.cross(o, tot[:, :3])
    return Pose(2.0 * jnp.sum(fw.axes * tau[:, None, :], axis=-1), 2.0 * sm[4 * nj])


@checked
def ik_gradient_naive(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` in the naive three-loop form (eq. (9)); same pytree as ``pose``."""
    fw = ik_forward(model, pose)
    return gradient_naive_from_forward(model, fw, fw.markers - targets)


@checked
def ik_gradient_factored(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` in the factored two-loop form (eq. (13)); same pytree as ``pose``."""
    fw = ik_forward(model, pose)
    return gradient_factored_from_forward(model, fw, fw.markers - targets)


@checked
def ik_gradient_autodiff(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` by ``jax.grad`` of `ik_objective` (reverse mode through the forward pass)."""
    return jax.grad(ik_objective, argnums=1)(model, pose, targets)


@checked
def value_and_gradient(
    gradient: Gradient, model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> tuple[Float[Array, ""], Pose]:
    """``(E, ∇E)`` from one forward pass, with the chosen gradient form.

    **Arguments:** `gradient`: ``"factored"`` (eq. (13)), ``"naive"`` (eq. (9)) or
    ``"autodiff"`` (``jax.value_and_grad``); `model`, `pose`, `targets` as
    `ik_gradient_factored`.

    **Returns:** the objective and its gradient (a `fxspace.Pose`).
    """
    if gradient == "autodiff":
        return jax.value_and_grad(ik_objective, argnums=1)(model, pose, targets)
    fw = ik_forward(model, pose)
    delta = fw.markers - targets
    kernel = gradient_naive_from_forward if gradient == "naive" else gradient_factored_from_forward
    return jnp.sum(delta * delta), kernel(model, fw, delta)


@checked
def ik_jacobian(
    model: IKModel, pose: Pose
) -> tuple[Float[Array, "markers 3"], Float[Array, "markers 3 joints 3"]]:
    """Marker positions and the Jacobian ``∂p_k/∂θ_ad = ω_ad × P_ka``.

    ``P_ka = Σ_{j ∈ desc(a)} (q_kj − W_kj o_a) = Q_ka − (Σ_{j ∈ desc(a)} W_kj) o_a`` with
    ``Q_ka = Σ_{j ∈ desc(a)} q_kj``: the factored form again, per marker, as dense products
    with the ``(J, J)`` descendant matrix.
    The translation block is the identity for every marker. ``O(K·J²)`` multiply-adds.
    """
    fw = ik_forward(model, pose)
    p = lever_arms(model, fw)
    jac = jnp.cross(fw.axes[None, :, :, :], p[:, :, None, :])  # (K, J, dof, xyz)
    return fw.markers, jnp.transpose(jac, (0, 3, 1, 2))


def lever_arms(model: IKModel, fw: IKForward) -> Float[Array, "markers joints 3"]:
    """``P_ka = Σ_{j ∈ desc(a)} (q_kj − W_kj o_a)`` (dense, through the descendant matrix)."""
    nj = fw.origins.shape[0]
    u = model.skin[: 3 * nj].reshape(nj, 3, -1)  # u_kjc as [j, c, k]
    w = model.skin[3 * nj : 4 * nj]  # W_kj as [j, k]
    q = w.T[..., None] * fw.origins[None] + jnp.einsum("jrc,jck->kjr", fw.linear, u)  # (K, J, 3)
    qa = jnp.einsum("aj,kjc->kac", model.descendants, q)
    subtree = (model.descendants @ w).T  # Σ_{j ∈ desc(a)} W_kj, (K, J)
    return qa - subtree[..., None] * fw.origins[None]


@checked
def ik_normal_equations(
    model: IKModel,
    pose: Pose,
    targets: Float[Array, "markers 3"],
    weights: Float[Array, " markers"] | None = None,
) -> tuple[Float[Array, "markers 3"], Float[Array, " n"], Float[Array, "n n"]]:
    """Residuals ``δ``, ``JᵀWδ`` and ``JᵀWJ`` (flat pose order: angles, then translation).

    `weights` (optional, ``(K,)``) weights each marker's squared distance (``W`` above;
    default: all ones). See `marker_normal_equations`.
    """
    fw = ik_forward(model, pose)
    r = fw.markers - targets
    g, h = marker_normal_equations(fw, lever_arms(model, fw), r, weights)
    return r, g, h


def marker_normal_equations(
    fw: IKForward,
    p: Float[Array, "markers joints 3"],
    r: Float[Array, "markers 3"],
    weights: Float[Array, " markers"] | None = None,
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """``JᵀWr`` and ``JᵀWJ`` of the marker residuals from a forward pass and the lever arms.

    Uses the structure ``J_k[:, ad] = −[P_ka]× ω_ad``: ``Σ_k w_k [P_ka]×ᵀ[P_kb]× =
    tr(G_ab) I − G_abᵀ`` with ``G_ab = Σ_k w_k P_ka P_kbᵀ``, one ``(3J × K) · (K × 3J)``
    product (a third of the multiply-adds of forming ``JᵀJ`` from the ``3K × 3J``
    Jacobian), then ``ω``-projections per joint pair.
    """
    nk, nj = p.shape[0], p.shape[1]
    w = fw.axes  # (J, dof, xyz)
    wr = r if weights is None else weights[:, None] * r
    g_ang = jnp.einsum("jdc,jc->jd", w, jnp.cross(p, wr[:, None, :]).sum(axis=0))
    pf = p.reshape(nk, 3 * nj)
    pw = pf if weights is None else weights[:, None] * pf
    gm = (pw.T @ pf).reshape(nj, 3, nj, 3)  # G[a, c, b, f] = Σ_k w_k P_ka,c P_kb,f
    tr = jnp.einsum("acbc->ab", gm)
    eye = jnp.eye(3, dtype=p.dtype)
    m = tr[:, None, :, None] * eye[None, :, None, :] - jnp.transpose(gm, (0, 3, 2, 1))
    # ω-projections per joint pair, one side at a time (XLA:CPU picks a slow order for the
    # three-operand einsum)
    wm = jnp.einsum("adc,acbf->adbf", w, m)
    h_ang = jnp.einsum("adbf,bef->adbe", wm, w).reshape(3 * nj, 3 * nj)
    s = pw.reshape(nk, nj, 3).sum(axis=0)  # (J, 3)
    h_at = jnp.cross(w, s[:, None, :]).reshape(3 * nj, 3)
    wsum = nk if weights is None else jnp.sum(weights)
    h = jnp.concatenate(
        [
            jnp.concatenate([h_ang, h_at], axis=1),
            jnp.concatenate([h_at.T, wsum * eye], axis=1),
        ],
        axis=0,
    )
    g = jnp.concatenate([g_ang.reshape(-1), wr.sum(axis=0)])
    return g, h


def gram_normal_equations(
    model: IKModel,
    pose: Pose,
    targets: Float[Array, "markers 3"],
    weights: Float[Array, " markers"] | None = None,
) -> tuple[Float[Array, ""], Float[Array, " n"], Float[Array, "n n"], GramParts]:
    """``(E_w, JᵀWr, JᵀWJ)`` of the marker residuals in few kernels (the
    Levenberg–Marquardt kernel), plus the markers, lever arms and axes on the way.

    The same normal equations as `ik_normal_equations` (``tr(G_ab) I − G_abᵀ``, see
    `marker_normal_equations`), laid out with the markers minor (on XLA:CPU at J = 19,
    K = 120 every kernel launch and every transposing copy costs about as much as the
    arithmetic):

    - dense contributions ``q_jk = L_j u_kj + W_kj o_j`` (``(J, 3, K)``, one batched
      product with the model's dense skinning) and their subtree sums, one product with
      the descendant matrix, whose extra row of ones gives the markers ``p_k = Σ_j q_jk``;
    - ``P_ka = Σ_{j ∈ desc(a)} q_jk − (Σ_{j ∈ desc(a)} W_kj) o_a``;
    - one product ``A (W A)ᵀ`` of the ``(3J + 4, K)`` matrix ``A = [P; r; 1]``: ``G``, the
      ``Σ_k w_k P_ka r_kᵀ`` of the gradient, ``Σ_k w_k P_ka`` of the angle–translation
      block, ``Σ_k w_k r_k``, ``E_w`` and ``Σ_k w_k`` at once;
    - the ω-projections per joint pair, as `marker_normal_equations`.
    """
    nj, nk = model.ancestors.shape[0], targets.shape[0]
    n3 = 3 * nj
    frames, w = ik_frames(model, pose.angles)  # w: axes (J, dof, xyz)
    o = frames[:, :3, 3] + pose.translation[None, :]
    wk = model.skin[n3 : 4 * nj]  # W_kj as [j, k]
    uw = jnp.concatenate([model.skin[:n3].reshape(nj, 3, nk), wk[:, None, :]], axis=1)
    go = jnp.concatenate([frames[:, :3, :3], o[:, :, None]], axis=2)  # [L_j | o_j]
    q = jnp.einsum("jrc,jck->jrk", go, uw)  # (J, 3, K)
    dd = jnp.concatenate([model.descendants, jnp.ones((1, nj), q.dtype)], axis=0)
    qa = (dd @ q.reshape(nj, 3 * nk)).reshape(nj + 1, 3, nk)
    subtree = model.descendants @ wk  # Σ_{j ∈ desc(a)} W_kj (pose-independent: hoisted)
    p = qa[:nj] - subtree[:, None, :] * o[:, :, None]  # (J, 3, K)
    r = qa[nj] - targets.T  # (3, K)
    pad = jnp.zeros((-(n3 + 4) % 8, nk), r.dtype)  # rows to a multiple of 8: ~20 % faster
    a = jnp.concatenate([p.reshape(n3, nk), r, jnp.ones((1, nk), r.dtype), pad], axis=0)
    c = a @ (a if weights is None else a * weights[None, :]).T  # (3J + 4 + pad)²
    gm = c[:n3, :n3].reshape(nj, 3, nj, 3)  # G[a, c, b, f] = Σ_k w_k P_ka,c P_kb,f
    x = c[:n3, n3 : n3 + 3].reshape(nj, 3, 3)  # Σ_k w_k P_ka,c r_k,f
    s = c[:n3, n3 + 3].reshape(nj, 3)  # Σ_k w_k P_ka
    cross = jnp.stack(
        [x[:, 1, 2] - x[:, 2, 1], x[:, 2, 0] - x[:, 0, 2], x[:, 0, 1] - x[:, 1, 0]], axis=-1
    )  # Σ_k w_k P_ka × r_k
    g_ang = jnp.sum(w * cross[:, None, :], axis=-1)
    tr = gm[:, 0, :, 0] + gm[:, 1, :, 1] + gm[:, 2, :, 2]
    eye = np.eye(3, dtype=p.dtype)  # a literal: no kernel builds it
    m = tr[:, None, :, None] * eye[None, :, None, :] - jnp.transpose(gm, (0, 3, 2, 1))
    wm = jnp.einsum("adc,acbf->adbf", w, m)
    # the second projection elementwise (as a product it needs a transposing copy)
    h_ang = sum(wm[:, :, :, None, f] * w[None, None, :, :, f] for f in range(3)).reshape(n3, n3)
    h_at = jnp.cross(w, s[:, None, :]).reshape(n3, 3)
    h = jnp.concatenate(
        [
            jnp.concatenate([h_ang, h_at], axis=1),
            jnp.concatenate([h_at.T, c[n3 + 3, n3 + 3] * eye], axis=1),
        ],
        axis=0,
    )
    g = jnp.concatenate([g_ang.reshape(-1), c[n3 : n3 + 3, n3 + 3]])
    obj = c[n3, n3] + c[n3 + 1, n3 + 1] + c[n3 + 2, n3 + 2]
    return obj, g, h, GramParts(qa[nj].T, p, w)
