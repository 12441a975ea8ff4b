"""Inverse kinematics for linear-blend-skinned meshes (Park, Kang & Kwon).

Markers ``p_k(θ)`` lie on the skinned mesh (:mod:`fxspace.mesh._markers`); given targets
``t_k`` the pose ``θ`` (per-joint XYZ Euler angles + a world translation, see
:class:`fxspace.Pose`) minimises the paper's eq. (1)/(7)

    E(θ) = Σ_k ‖p_k(θ) − t_k‖² = Σ_k ‖δ_k‖²,    p_k = Σ_j (W_kj o_j + L_j u_kj).

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
* **autodiff**: ``jax.grad`` of :func:`ik_objective`.

All three share the same forward pass (:func:`ik_forward`: global transforms, joint
origins and axes, marker contributions), so timing them compares the gradient
arithmetic and nothing else. On XLA:CPU at J = 19, K = 120 every kernel launch costs
about as much as its arithmetic, so the forward pass is written for few kernels, with
every pose-independent quantity precomputed by :func:`ik_model` (rest transforms folded
with the base transforms, pointer-jumping tables, axis scales, the packed skinning
matrices); it still costs about as much as the factored gradient, which bounds the
full-call speed-up (``experiments/bench_ik.py`` times the full call, the full
evaluation inside a jitted loop, the forward pass and the arithmetic alone). The
analytic per-marker Jacobian (:func:`ik_jacobian`) feeds a Levenberg–Marquardt solver;
:func:`solve_ik` also offers optimistix's Levenberg–Marquardt / Gauss–Newton and a
first-order optax (Adam) variant.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from fxspace.errors import FxspaceError
from fxspace.mesh._markers import MarkerSet, marker_influences
from fxspace.mesh._skinning import (
    Pose,
    ancestor_table,
    chain_bases,
)
from fxspace.rotations import quat_normalize, quat_to_matrix

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import SkinnedMesh

__all__ = [
    "IKModel",
    "IKForward",
    "IKResult",
    "ik_model",
    "ik_forward",
    "ik_markers",
    "ik_residuals",
    "ik_objective",
    "ik_gradient_naive",
    "ik_gradient_factored",
    "ik_gradient_autodiff",
    "ik_jacobian",
    "ik_normal_equations",
    "solve_ik",
    "track_ik",
    "METHODS",
    "GRADIENTS",
]

METHODS = ("lm", "optx_lm", "optx_gn", "adam")
GRADIENTS = ("factored", "naive", "autodiff")


class IKModel(NamedTuple):
    """Everything the IK objective needs, as arrays (a pytree: pass it through ``jit``/``vmap``).

    Build it with :func:`ik_model`; every field is pose-independent (precomputed once):

    - ``local_rest[j]``: the ``4×4`` transform ``T_j · R_rest,j`` of joint ``j``,
      premultiplied by the fixed base transform above it for roots, so that the posed local
      transform is ``local_rest[j] · diag(R_x R_y R_z · S_j, 1)``;
    - ``hops[s]``: the ``(2, J)`` ancestor tables of step ``s`` of the ternary pointer
      jumping in :func:`ik_forward` (the ``3^s``-th and ``2·3^s``-th ancestor, ``-1`` for
      none);
    - ``scales[j] = (s_jx, s_jy, s_jz, 1/σ_j)``: the joint's rest scale ``S_j`` and the
      inverse of the global scale ``σ_j`` of its frame ``G_j S_j⁻¹`` (pose-independent for
      rotation + uniform scale; normalises the rotation axes);
    - ``ancestors``: the ``(J, D)`` ancestor table padded with ``J`` (the naive gradient);
    - ``marker_joints``, ``marker_skin``: the sparse skinning of the markers
      (:func:`fxspace.marker_influences`, ``N`` joints per marker), ``marker_skin[k, n] =
      [u_kn; W_kn]`` (local position and weight: ``q_kn = G_j [u_kn; W_kn]``; the forward
      pass and the naive gradient);
    - ``descendants[a, j] = 1`` when ``a`` is ``j`` or one of its ancestors;
    - ``skin``: the dense marker skinning, transposed and stacked, ``(4J + 1, K)``: rows
      ``3j + c`` hold ``u_kjc``, rows ``3J + j`` hold ``W_kj`` and the last row is ones
      (the factored gradient: one product with ``δ`` gives every per-joint sum and
      ``Σ_k δ_k``; the Jacobian);
    - ``length_scale``: the mesh's bounding-box diagonal (scale-free tolerances).
    """

    local_rest: Float[Array, "joints 4 4"]
    hops: Int[Array, "steps 2 joints"]
    scales: Float[Array, "joints 4"]  # (S_j, 1/σ_j)
    ancestors: Int[Array, "joints depth"]
    marker_joints: Int[Array, "markers n"]
    marker_skin: Float[Array, "markers n 4"]  # [u_kn; W_kn]
    length_scale: Float[Array, ""]
    descendants: Float[Array, "joints joints"]  # [a, j] = 1 when a is j or an ancestor of j
    skin: Float[Array, "rows markers"]  # [u_kjc; W_kj; 1] transposed, 4J + 1 rows


class IKForward(NamedTuple):
    """The forward pass shared by the objective and the three gradients."""

    origins: Float[Array, "joints 3"]  # o_j
    axes: Float[Array, "joints 3 3"]  # ω_jd (unit, world), [joint, dof, xyz]
    linear: Float[Array, "joints 3 3"]  # L_j
    contributions: Float[Array, "markers n 3"]  # q_kj
    markers: Float[Array, "markers 3"]  # p_k


class IKResult(NamedTuple):
    """Result of :func:`solve_ik`: the pose and diagnostics.

    ``residual`` is the RMS marker distance ``sqrt(E / K)`` (the mesh's units),
    ``objective`` is ``E`` (eq. (1)), ``converged`` says whether the tolerance was met
    within ``max_steps``.
    """

    pose: Pose
    residual: Float[Array, ""]
    objective: Float[Array, ""]
    num_steps: Int[Array, ""]
    converged: Bool[Array, ""]


def _quaternion_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """:func:`fxspace.quaternion_to_matrix` in float64 numpy (host-side precomputation)."""
    return quat_to_matrix(quat_normalize(np.asarray(q, dtype=np.float64)), order="xyzw")


def _hop_tables(anc: np.ndarray) -> np.ndarray:
    """``(steps, 2, J)``: for ternary pointer jumping, the ``3^s``-th and ``2·3^s``-th
    ancestor of each joint (``-1`` past the root); ``3^steps ≥ D``."""
    nj, depth = anc.shape
    steps, span = 0, 1
    while span < depth:
        steps, span = steps + 1, span * 3

    def up(n: int) -> np.ndarray:
        if n >= depth:
            return np.full(nj, -1, np.int64)
        col = anc[:, n].astype(np.int64)
        return np.where(col < nj, col, -1)

    return np.array([[up(3**s), up(2 * 3**s)] for s in range(steps)], dtype=np.int32).reshape(
        steps, 2, nj
    )


def ik_model(mesh: SkinnedMesh, markers: MarkerSet, dtype=None) -> IKModel:
    """Precompute the :class:`IKModel` of ``mesh`` with ``markers`` (host-side, once).

    Refuses skeletons with non-uniform joint scales, or base transforms that are not
    similarities (the rotation axes of the analytic gradients assume rotation + uniform
    scale, and their normalisation is precomputed); uniform scales are fine.
    """
    s = np.asarray(mesh.rest_scales, dtype=np.float64)
    if np.any(
        np.abs(s - s.mean(axis=1, keepdims=True)) > 1e-5 * np.abs(s).max(axis=1, keepdims=True)
    ):
        raise FxspaceError(
            f"{mesh.name}: non-uniform joint scales are not supported by the IK model "
            "(analytic gradients assume rotation + uniform scale); bake the scales into the mesh"
        )
    dtype = dtype or jnp.result_type(float)
    anc = ancestor_table(mesh.parents)
    inf = marker_influences(mesh, markers)
    ext = np.ptp(np.asarray(mesh.vertices), axis=0)
    nj, nk = mesh.num_joints, inf.joints.shape[0]
    parents = np.asarray(mesh.parents)
    # local_rest = P_j · [R_rest | t], P_j = the base transform above root j (else I)
    rot = _quaternion_to_matrix_np(np.asarray(mesh.rest_rotations, dtype=np.float64))
    local = np.tile(np.eye(4), (nj, 1, 1))
    local[:, :3, :3] = rot
    local[:, :3, 3] = np.asarray(mesh.rest_translations, dtype=np.float64)
    base = chain_bases(mesh.base_transforms, anc)
    local = np.where((parents < 0)[:, None, None], base @ local, local)
    glob = np.zeros_like(local)  # rest-pose global frames G_j S_j⁻¹ (for the axis scales)
    for j in np.argsort((anc < nj).sum(axis=1), kind="stable"):
        if parents[j] < 0:
            glob[j] = local[j]
        else:
            glob[j] = glob[parents[j]] @ np.diag(np.append(s[parents[j]], 1.0)) @ local[j]
    lin = glob[:, :3, :3]
    sigma = np.cbrt(np.abs(np.linalg.det(lin)))
    gram = np.einsum("jrc,jsc->jrs", lin, lin) / (sigma**2)[:, None, None]
    if np.any(np.abs(gram - np.eye(3)) > 1e-5):
        raise FxspaceError(
            f"{mesh.name}: the transforms above the skeleton are not rotation + uniform scale; "
            "the IK model needs similarity transforms (bake the scales into the mesh)"
        )
    desc = np.zeros((nj, nj))
    for j in range(nj):
        desc[anc[j][anc[j] < nj], j] = 1.0
    wd = np.zeros((nk, nj))
    ud = np.zeros((nk, nj, 3))
    rows = np.repeat(np.arange(nk), inf.joints.shape[1])
    np.add.at(wd, (rows, inf.joints.reshape(-1)), inf.weights.reshape(-1))
    np.add.at(ud, (rows, inf.joints.reshape(-1)), inf.offsets.reshape(-1, 3))
    skin = np.concatenate([ud.transpose(1, 2, 0).reshape(3 * nj, nk), wd.T, np.ones((1, nk))])
    a = lambda x: jnp.asarray(x, dtype=dtype)
    return IKModel(
        local_rest=a(local),
        hops=jnp.asarray(_hop_tables(anc), dtype=jnp.int32),
        scales=a(np.concatenate([s, 1.0 / sigma[:, None]], axis=1)),
        ancestors=jnp.asarray(anc, dtype=jnp.int32),
        marker_joints=jnp.asarray(inf.joints, dtype=jnp.int32),
        marker_skin=a(np.concatenate([inf.offsets, inf.weights[..., None]], axis=-1)),
        length_scale=a(float(np.linalg.norm(ext)) or 1.0),
        descendants=a(desc),
        skin=a(np.ascontiguousarray(skin)),
    )


def _mm_unrolled(a: Array, b: Array) -> Array:
    """``a @ b`` over the last two axes, the contraction written out (elementwise: fuses)."""
    return sum(a[..., :, i : i + 1] * b[..., i : i + 1, :] for i in range(a.shape[-1]))


def _mm_reduce(a: Array, b: Array) -> Array:
    """``a @ b`` over the last two axes as multiply + reduce (one fused kernel, whose
    result XLA materialises rather than recomputing it in every consumer)."""
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def _euler_rows(e: Float[Array, "joints 3"]) -> tuple[Array, Array, Array]:
    """``R_x(θ_0) R_y(θ_1) R_z(θ_2)`` per joint, and ``(cos, sin)`` of ``θ_2``."""
    c, s = jnp.cos(e), jnp.sin(e)
    cx, cy, cz = c[:, 0], c[:, 1], c[:, 2]
    sx, sy, sz = s[:, 0], s[:, 1], s[:, 2]
    rows = [
        [cy * cz, -cy * sz, sy],
        [cx * sz + sx * sy * cz, cx * cz - sx * sy * sz, -sx * cy],
        [sx * sz - cx * sy * cz, sx * cz + cx * sy * sz, cx * cy],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2), cz, sz


def ik_forward(model: IKModel, pose: Pose) -> IKForward:
    """Forward kinematics + marker skinning at ``pose`` (shared by all gradient forms).

    Written for few kernels (on XLA:CPU at this size every kernel launch costs about as
    much as its arithmetic), with everything pose-independent precomputed in the model:

    - posed local transforms: one elementwise kernel, ``local_rest · diag(E_j S_j, 1)``
      with ``E_j = R_x R_y R_z``;
    - global transforms: ``⌈log₃ D⌉`` steps of ternary pointer jumping (after step ``s``
      each joint holds the product of the ``3^(s+1)`` links above it,
      ``G ← G[2·3^s-th ancestor] · G[3^s-th ancestor] · G``), one gather and one
      multiply-reduce kernel per step (two steps for CesiumMan's depth 6);
    - Euler axes from each joint's own frame, no parent gather: ``ω_x ∝ F_j E_jᵀ e_x``,
      ``ω_y ∝ F_j R_zᵀ e_y``, ``ω_z ∝ F_j e_z`` with ``F_j = L_j S_j⁻¹``, normalised by the
      precomputed ``1/σ_j`` (exact for rotation + uniform scale), one batched product;
    - marker contributions ``q_kn = G_j [u_kn; W_kn]``: one gather + batched product.

    The axes and contributions come out of products, i.e. as materialised arrays, so the
    naive gradient's ``(K, N, D)`` gathers read them instead of XLA fusing (and
    recomputing) the forward pass into its own kernels: both analytic gradients pay for
    the same forward pass.
    """
    rot, cz, sz = _euler_rows(pose.angles)
    lr, sc = model.local_rest, model.scales
    rs = rot * sc[:, None, :3]  # R_x R_y R_z S_j
    g = jnp.concatenate([_mm_unrolled(lr[:, :, :3], rs), lr[:, :, 3:]], axis=2)  # (J, 4, 4)
    eye = jnp.eye(4, dtype=g.dtype)
    for step in range(model.hops.shape[0]):
        h = model.hops[step]  # (2, J)
        up = jnp.where((h >= 0)[:, :, None, None], g[jnp.maximum(h, 0)], eye[None, None])
        g = _mm_reduce(_mm_unrolled(up[1], up[0]), g)
    o = g[:, :3, 3] + pose.translation[None, :]
    lin = g[:, :3, :3]
    # ω_jd = L_j S_j⁻¹ v_jd / σ_j with v_jx = E_jᵀ e_x, v_jy = R_zᵀ e_y, v_jz = e_z
    zero = jnp.zeros_like(cz)
    v = jnp.stack(
        [rot[:, 0, :], jnp.stack([sz, cz, zero], -1), jnp.stack([zero, zero, zero + 1], -1)], 1
    )
    v = v * (sc[:, 3:] / sc[:, :3])[:, None, :]
    v = jnp.concatenate([v, jnp.zeros_like(v[..., :1])], axis=-1)
    axes = jnp.einsum("jrc,jdc->jdr", g, v)[..., :3]  # (J, dof, xyz)
    gm = g[model.marker_joints][..., :3, :]  # (K, N, 3, 4)
    uw = model.marker_skin
    q = jnp.einsum("knrc,knc->knr", gm, uw) + uw[..., 3:] * pose.translation[None, None, :]
    return IKForward(o, axes, lin, q, q.sum(axis=1))


def ik_markers(model: IKModel, pose: Pose) -> Float[Array, "markers 3"]:
    """Marker positions ``p_k(θ)``."""
    return ik_forward(model, pose).markers


def ik_residuals(
    model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> Float[Array, "markers 3"]:
    """``δ_k = p_k(θ) − t_k``."""
    return ik_markers(model, pose) - targets


def ik_objective(
    model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> Float[Array, ""]:
    """``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` (the paper's eq. (1)/(7))."""
    d = ik_residuals(model, pose, targets)
    return jnp.sum(d * d)


def _pad(x: Array) -> Array:
    return jnp.concatenate([x, jnp.zeros((1,) + x.shape[1:], x.dtype)], axis=0)


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


def ik_gradient_naive(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` in the naive three-loop form (eq. (9)); same pytree as ``pose``."""
    fw = ik_forward(model, pose)
    return gradient_naive_from_forward(model, fw, fw.markers - targets)


def ik_gradient_factored(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` in the factored two-loop form (eq. (13)); same pytree as ``pose``."""
    fw = ik_forward(model, pose)
    return gradient_factored_from_forward(model, fw, fw.markers - targets)


def ik_gradient_autodiff(model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]) -> Pose:
    """``∇E`` by ``jax.grad`` of :func:`ik_objective` (reverse mode through the forward pass)."""
    return jax.grad(ik_objective, argnums=1)(model, pose, targets)


_GRAD = {
    "naive": ik_gradient_naive,
    "factored": ik_gradient_factored,
    "autodiff": ik_gradient_autodiff,
}


def _value_and_grad(gradient: str, model: IKModel, pose: Pose, targets) -> tuple[Array, Pose]:
    """``(E, ∇E)`` from one forward pass, with the chosen gradient form."""
    if gradient == "autodiff":
        return jax.value_and_grad(ik_objective, argnums=1)(model, pose, targets)
    fw = ik_forward(model, pose)
    delta = fw.markers - targets
    kernel = gradient_naive_from_forward if gradient == "naive" else gradient_factored_from_forward
    return jnp.sum(delta * delta), kernel(model, fw, delta)


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
    p = _lever_arms(model, fw)
    jac = jnp.cross(fw.axes[None, :, :, :], p[:, :, None, :])  # (K, J, dof, xyz)
    return fw.markers, jnp.transpose(jac, (0, 3, 1, 2))


def _lever_arms(model: IKModel, fw: IKForward) -> Float[Array, "markers joints 3"]:
    """``P_ka = Σ_{j ∈ desc(a)} (q_kj − W_kj o_a)`` (dense, through the descendant matrix)."""
    nj = fw.origins.shape[0]
    u = model.skin[: 3 * nj].reshape(nj, 3, -1)  # u_kjc as [j, c, k]
    w = model.skin[3 * nj : 4 * nj]  # W_kj as [j, k]
    q = w.T[..., None] * fw.origins[None] + jnp.einsum("jrc,jck->kjr", fw.linear, u)  # (K, J, 3)
    qa = jnp.einsum("aj,kjc->kac", model.descendants, q)
    subtree = (model.descendants @ w).T  # Σ_{j ∈ desc(a)} W_kj, (K, J)
    return qa - subtree[..., None] * fw.origins[None]


def ik_normal_equations(
    model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> tuple[Float[Array, "markers 3"], Float[Array, " n"], Float[Array, "n n"]]:
    """Residuals ``δ``, ``Jᵀδ`` and ``JᵀJ`` (flat pose order: angles, then translation).

    Uses the structure ``J_k[:, ad] = −[P_ka]× ω_ad``: ``Σ_k [P_ka]×ᵀ[P_kb]× =
    tr(G_ab) I − G_abᵀ`` with ``G_ab = Σ_k P_ka P_kbᵀ``, one ``(3J × K) · (K × 3J)``
    product (a third of the multiply-adds of forming ``JᵀJ`` from the ``3K × 3J``
    Jacobian), then ``ω``-projections per joint pair.
    """
    fw = ik_forward(model, pose)
    p = _lever_arms(model, fw)  # (K, J, 3)
    nk, nj = p.shape[0], p.shape[1]
    r = fw.markers - targets
    w = fw.axes  # (J, dof, xyz)
    g_ang = jnp.einsum("jdc,jc->jd", w, jnp.cross(p, r[:, None, :]).sum(axis=0))
    pf = p.reshape(nk, 3 * nj)
    gm = (pf.T @ pf).reshape(nj, 3, nj, 3)  # G[a, c, b, f] = Σ_k P_ka,c P_kb,f
    tr = jnp.einsum("acbc->ab", gm)
    eye = jnp.eye(3, dtype=p.dtype)
    m = tr[:, None, :, None] * eye[None, :, None, :] - jnp.transpose(gm, (0, 3, 2, 1))
    h_ang = jnp.einsum("adc,acbf,bef->adbe", w, m, w).reshape(3 * nj, 3 * nj)
    s = p.sum(axis=0)  # (J, 3)
    h_at = jnp.cross(w, s[:, None, :]).reshape(3 * nj, 3)
    h = jnp.concatenate(
        [
            jnp.concatenate([h_ang, h_at], axis=1),
            jnp.concatenate([h_at.T, nk * eye], axis=1),
        ],
        axis=0,
    )
    g = jnp.concatenate([g_ang.reshape(-1), r.sum(axis=0)])
    return r, g, h


# ----------------------------------------------------------------------------- solvers


def _flat(pose: Pose) -> Array:
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


def _unflat(x: Array, nj: int) -> Pose:
    return Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :])


def _result(model: IKModel, pose: Pose, targets, steps, converged) -> IKResult:
    d = ik_residuals(model, pose, targets)
    obj = jnp.sum(d * d)
    rms = jnp.sqrt(obj / d.shape[0])
    return IKResult(pose, rms, obj, jnp.asarray(steps, jnp.int32), jnp.asarray(converged))


def _solve_lm(model, targets, init, max_steps, rtol, atol):
    """Levenberg–Marquardt with the analytic Jacobian and Nielsen's damping update."""
    nj = model.ancestors.shape[0]
    nk = targets.shape[0]
    npar = 3 * nj + 3
    abs_obj = (atol * model.length_scale) ** 2 * nk

    def lin(x):
        r, g, h = ik_normal_equations(model, _unflat(x, nj), targets)
        return r.reshape(-1), g, h

    x0 = _flat(init)
    r0, g0, h0 = lin(x0)
    obj0 = r0 @ r0
    # carry: x, r, g, H, obj, lam, nu, step, done, converged
    init_c = (
        x0,
        r0,
        g0,
        h0,
        obj0,
        jnp.asarray(1e-3, x0.dtype),
        jnp.asarray(2.0, x0.dtype),
        jnp.asarray(0),
        obj0 <= abs_obj,
        obj0 <= abs_obj,
    )

    def cond(c):
        return (c[7] < max_steps) & ~c[8]

    def body(c):
        x, r, g, h, obj, lam, nu, step, _, _ = c
        dg = jnp.diagonal(h)
        damp = lam * (dg + 1e-12 * (jnp.max(dg) + 1.0))
        dx = jnp.linalg.solve(h + jnp.diag(damp), -g)
        xn = x + dx
        dn = ik_residuals(model, _unflat(xn, nj), targets).reshape(-1)
        objn = dn @ dn
        pred = -(2.0 * g @ dx + dx @ h @ dx)
        rho = (obj - objn) / jnp.maximum(pred, 1e-300)
        ok = (objn < obj) & jnp.isfinite(objn)
        r2, g2, h2 = jax.lax.cond(ok, lambda: lin(xn), lambda: (r, g, h))
        x2 = jnp.where(ok, xn, x)
        obj2 = jnp.where(ok, objn, obj)
        lam2 = jnp.where(ok, lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), lam * nu)
        nu2 = jnp.where(ok, 2.0, nu * 2.0)
        small_step = jnp.max(jnp.abs(dx)) <= 1e-12
        conv = (obj2 <= abs_obj) | (ok & (obj - objn <= rtol * obj)) | small_step
        stuck = ~jnp.isfinite(lam2) | (lam2 > 1e16)
        return (x2, r2, g2, h2, obj2, lam2, nu2, step + 1, conv | stuck, conv)

    out = jax.lax.while_loop(cond, body, init_c)
    del npar
    return _unflat(out[0], nj), out[7], out[9]


def _solve_optx(model, targets, init, max_steps, rtol, atol, method):
    import optimistix as optx

    def fn(pose, args):
        return ik_residuals(model, pose, targets)

    tol = dict(rtol=rtol, atol=atol * model.length_scale)
    solver = optx.LevenbergMarquardt(**tol) if method == "optx_lm" else optx.GaussNewton(**tol)
    sol = optx.least_squares(fn, solver, init, max_steps=max_steps, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def _solve_adam(model, targets, init, max_steps, rtol, atol, gradient, learning_rate):
    import optax

    scale = model.length_scale
    nk = targets.shape[0]
    abs_obj = (atol * scale) ** 2 * nk
    opt = optax.adam(learning_rate)
    # optimise the translation in units of the mesh size, so one learning rate fits both blocks
    params0 = Pose(init.angles, init.translation / scale)
    state0 = opt.init(params0)

    def cond(c):
        return (c[2] < max_steps) & ~c[3]

    def body(c):
        params, state, step, _ = c
        pose = Pose(params.angles, params.translation * scale)
        obj, g = _value_and_grad(gradient, model, pose, targets)
        g = Pose(g.angles, g.translation * scale)
        upd, state = opt.update(g, state, params)
        params = optax.apply_updates(params, upd)
        # converged when the objective before this update was already below the tolerance
        return params, state, step + 1, obj <= abs_obj

    out = jax.lax.while_loop(cond, body, (params0, state0, jnp.asarray(0), jnp.asarray(False)))
    params, _, steps, conv = out
    del rtol
    return Pose(params.angles, params.translation * scale), steps, conv


@partial(jax.jit, static_argnames=("method", "gradient", "max_steps"))
def _solve(model, targets, init, method, gradient, max_steps, rtol, atol, learning_rate):
    if method == "lm":
        pose, steps, conv = _solve_lm(model, targets, init, max_steps, rtol, atol)
    elif method in ("optx_lm", "optx_gn"):
        pose, steps, conv = _solve_optx(model, targets, init, max_steps, rtol, atol, method)
    else:
        pose, steps, conv = _solve_adam(
            model, targets, init, max_steps, rtol, atol, gradient, learning_rate
        )
    return _result(model, pose, targets, steps, conv)


def _check(model: IKModel, targets, init, method: str, gradient: str, max_steps: int):
    if method not in METHODS:
        raise FxspaceError(f"method must be one of {METHODS}, got {method!r}")
    if gradient not in GRADIENTS:
        raise FxspaceError(f"gradient must be one of {GRADIENTS}, got {gradient!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
        raise FxspaceError(f"max_steps must be a positive integer, got {max_steps!r}")
    nk = model.marker_joints.shape[0]
    if targets.shape[-2:] != (nk, 3):
        raise FxspaceError(
            f"targets must have shape (..., {nk}, 3) for this model's {nk} markers, "
            f"got {targets.shape}"
        )
    nj = model.ancestors.shape[0]
    if init is not None and (init.angles.shape != (nj, 3) or init.translation.shape != (3,)):
        raise FxspaceError(f"init must be a Pose with angles ({nj}, 3) and translation (3,)")


def solve_ik(
    model: IKModel,
    targets: Float[Array, "markers 3"],
    init: Pose | None = None,
    *,
    method: str = "lm",
    gradient: str = "factored",
    max_steps: int = 50,
    rtol: float = 1e-6,
    atol: float = 1e-7,
    learning_rate: float = 0.02,
) -> IKResult:
    """Pose that brings the markers to ``targets``: ``argmin_θ E(θ)`` (eq. (1)), one frame.

    **Arguments:**

    - `model`: from :func:`ik_model`.
    - `targets`: ``(K, 3)`` marker targets.
    - `init`: starting pose (default: the rest pose); pass the previous frame's pose to
      warm-start along an animation (:func:`track_ik` does this).
    - `method`: ``"lm"`` (Levenberg–Marquardt with the analytic Jacobian, the fastest),
      ``"optx_lm"`` / ``"optx_gn"`` (optimistix Levenberg–Marquardt / Gauss–Newton,
      Jacobian by autodiff), ``"adam"`` (first-order, optax Adam on ``gradient``).
    - `gradient`: for ``"adam"``: ``"factored"`` (eq. (13)), ``"naive"`` (eq. (9)) or
      ``"autodiff"``.
    - `max_steps`: iteration bound.
    - `rtol`: stop when an accepted step lowers ``E`` by less than ``rtol · E`` (LM), or
      the optimistix step tolerance.
    - `atol`: stop when the RMS marker residual is below ``atol × length_scale``.
    - `learning_rate`: Adam's step (radians; the translation is scaled by the mesh size).

    **Returns:** :class:`IKResult` (pose, RMS residual, objective, ``num_steps``, ``converged``).
    Jitted (the method, gradient and ``max_steps`` are static); vmappable over targets.
    """
    targets = jnp.asarray(targets)
    _check(model, targets, init, method, gradient, max_steps)
    if init is None:
        nj = model.ancestors.shape[0]
        init = Pose(jnp.zeros((nj, 3), targets.dtype), jnp.zeros((3,), targets.dtype))
    return _solve(model, targets, init, method, gradient, max_steps, rtol, atol, learning_rate)


@partial(jax.jit, static_argnames=("method", "gradient", "max_steps"))
def _track(model, targets, init, method, gradient, max_steps, rtol, atol, learning_rate):
    def step(pose, tgt):
        res = _solve(model, tgt, pose, method, gradient, max_steps, rtol, atol, learning_rate)
        return res.pose, res

    _, out = jax.lax.scan(step, init, targets)
    return out


def track_ik(
    model: IKModel,
    targets: Float[Array, "frames markers 3"],
    init: Pose | None = None,
    **kwargs,
) -> IKResult:
    """:func:`solve_ik` frame by frame along ``targets``, each frame warm-started from the last.

    One ``lax.scan``; returns an :class:`IKResult` whose fields have a leading frame axis.
    Keyword arguments as :func:`solve_ik`.
    """
    targets = jnp.asarray(targets)
    if targets.ndim != 3:
        raise FxspaceError(f"targets must be (frames, markers, 3), got shape {targets.shape}")
    opts = dict(
        method="lm", gradient="factored", max_steps=50, rtol=1e-6, atol=1e-7, learning_rate=0.02
    )
    unknown = set(kwargs) - set(opts)
    if unknown:
        raise FxspaceError(f"unknown option(s) {sorted(unknown)}; valid: {sorted(opts)}")
    opts.update(kwargs)
    _check(model, targets, init, opts["method"], opts["gradient"], opts["max_steps"])
    if init is None:
        nj = model.ancestors.shape[0]
        init = Pose(jnp.zeros((nj, 3), targets.dtype), jnp.zeros((3,), targets.dtype))
    return _track(
        model,
        targets,
        init,
        opts["method"],
        opts["gradient"],
        opts["max_steps"],
        opts["rtol"],
        opts["atol"],
        opts["learning_rate"],
    )
