"""The IK model and its forward pass (Park, Kang & Kwon, eqs. (1)-(7)).

Markers ``p_k(θ)`` lie on the skinned mesh (`fxspace.mesh._markers`); given targets
``t_k`` the pose ``θ`` (per-joint XYZ Euler angles + a world translation, see
`fxspace.Pose`) minimises the paper's eq. (1)/(7)

    E(θ) = Σ_k ‖p_k(θ) − t_k‖² = Σ_k ‖δ_k‖²,    p_k = Σ_j (W_kj o_j + L_j u_kj).

`ik_model` precomputes every pose-independent quantity once (host side);
`ik_forward` is the forward pass shared by the objective and the three gradient
forms of `fxspace.mesh._ik_gradients`, so timing them compares the gradient
arithmetic and nothing else. On XLA:CPU at J = 19, K = 120 every kernel launch costs
about as much as its arithmetic, so the forward pass is written for few kernels.

Example:

```python
mesh = fx.io.read_gltf("CesiumMan.glb")
model = fx.ik_model(mesh, fx.place_markers(mesh.vertices, mesh.faces, 50))
E = fx.ik_objective(model, fx.rest_pose(mesh), targets)
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.mesh._markers import MarkerSet, marker_influences
from fxspace.mesh._skinning import Pose, ancestor_table, chain_bases
from fxspace.results import RESULTS, member_code, result_code, result_messages
from fxspace.rotations import quat_normalize, quat_to_matrix

if TYPE_CHECKING:  # pragma: no cover
    from fxspace.mesh._types import SkinnedMesh

__all__ = [
    "IKModel",
    "IKForward",
    "IKResult",
    "IK_STATUS",
    "ik_model",
    "ik_forward",
    "ik_markers",
    "ik_residuals",
    "ik_objective",
]


class IKModel(NamedTuple):
    """Everything the IK objective needs, as arrays (a pytree: pass it through ``jit``/``vmap``).

    Build it with `ik_model`; every field is pose-independent (precomputed once):

    - ``local_rest[j]``: the ``4×4`` transform ``T_j · R_rest,j`` of joint ``j``,
      premultiplied by the fixed base transform above it for roots, so that the posed local
      transform is ``local_rest[j] · diag(R_x R_y R_z · S_j, 1)``;
    - ``hops[s]``: the ``(2, J)`` ancestor tables of step ``s`` of the ternary pointer
      jumping in `ik_forward` (the ``3^s``-th and ``2·3^s``-th ancestor, ``J`` for
      none: an identity appended to the transforms);
    - ``scales[j] = (s_jx, s_jy, s_jz, 1/σ_j)``: the joint's rest scale ``S_j`` and the
      inverse of the global scale ``σ_j`` of its frame ``G_j S_j⁻¹`` (pose-independent for
      rotation + uniform scale; normalises the rotation axes);
    - ``ancestors``: the ``(J, D)`` ancestor table padded with ``J`` (the naive gradient);
    - ``marker_joints``, ``marker_skin``: the sparse skinning of the markers
      (`fxspace.marker_influences`, ``N`` joints per marker), ``marker_skin[k, n] =
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


IK_STATUS: tuple[str, ...] = ("converged", "max_steps", "non_finite", "stalled")
"""Meaning of the compatibility field `IKResult.status` (an index into this tuple), kept
for old callers; the one declaration of how a solve ended is ``IKResult.result`` (a
`fxspace.RESULTS` member), and ``status`` is derived from it through `_STATUS_OF_RESULT`:
``successful`` → 0 ``"converged"``; ``max_steps_reached`` → 1 ``"max_steps"``;
``nonfinite_input`` / ``nonfinite_output`` → 2 ``"non_finite"`` (the returned pose is
the initial pose, never a made-up answer); ``stalled`` → 3 ``"stalled"``."""

_STATUS_OF_RESULT = {
    "successful": 0,
    "max_steps_reached": 1,
    "nonfinite_input": 2,
    "nonfinite_output": 2,
    "stalled": 3,
    "disconnected": 3,
    "poor_fit": 3,
}


def _status_table() -> np.ndarray:
    table = np.ones(len(result_messages()), np.int32)
    for name, code in _STATUS_OF_RESULT.items():
        table[member_code(getattr(RESULTS, name))] = code
    return table


_STATUS_TABLE = _status_table()


class IKResult(NamedTuple):
    """Result of `fxspace.solve_ik` / `fxspace.track_ik`: the pose and diagnostics.

    - ``pose``: the solved `fxspace.Pose`;
    - ``residual``: the RMS marker distance ``sqrt(E / K)`` over the markers with a
      positional weight (the mesh's units);
    - ``objective``: the value minimised, ``E`` (eq. (1)) plus every active constraint's
      squared residuals;
    - ``num_steps``: the solver's iterations;
    - ``result``: how the solve ended, a `fxspace.RESULTS` member
      (``res.result == fx.RESULTS.successful``); non-finite targets give
      ``RESULTS.nonfinite_input`` and the initial pose, never a plausible answer;
    - ``stats``: scalar diagnostics: ``"max_steps"`` (the solver's bound) and
      ``"objective"``.

    Compatibility: ``converged`` (``result == successful``) and ``status`` (an index into
    `IK_STATUS`) are properties derived from ``result``.
    """

    pose: Pose
    residual: Float[Array, ""]
    objective: Float[Array, ""]
    num_steps: Int[Array, ""]
    result: Any
    stats: dict

    @property
    def converged(self) -> Bool[Array, ...]:
        """``result == RESULTS.successful`` (a boolean array, one per frame for tracking)."""
        return self.result == RESULTS.successful

    @property
    def status(self) -> Int[Array, ...]:
        """The old integer status (an index into `IK_STATUS`), derived from ``result``."""
        return jnp.asarray(_STATUS_TABLE)[result_code(self.result)]


def _quaternion_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """`fxspace.quaternion_to_matrix` in float64 numpy (host-side precomputation)."""
    return quat_to_matrix(quat_normalize(np.asarray(q, dtype=np.float64)), order="xyzw")


def _hop_tables(anc: np.ndarray) -> np.ndarray:
    """``(steps, 2, J)``: for ternary pointer jumping, the ``3^s``-th and ``2·3^s``-th
    ancestor of each joint (``J`` past the root: the identity appended to the transforms in
    `ik_forward`, no mask); ``3^steps ≥ D``."""
    nj, depth = anc.shape
    steps, span = 0, 1
    while span < depth:
        steps, span = steps + 1, span * 3

    def up(n: int) -> np.ndarray:
        if n >= depth:
            return np.full(nj, nj, np.int64)
        return np.minimum(anc[:, n].astype(np.int64), nj)

    return np.array([[up(3**s), up(2 * 3**s)] for s in range(steps)], dtype=np.int32).reshape(
        steps, 2, nj
    )


@checked
def ik_model(mesh: SkinnedMesh, markers: MarkerSet, dtype=None) -> IKModel:
    """Precompute the `IKModel` of ``mesh`` with ``markers`` (host-side, once).

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


def _global_frames(model: IKModel, angles: Float[Array, "joints 3"]):
    """Posed global transforms ``G_j`` (without the world translation) by ternary pointer
    jumping, and the Euler axes' local directions ``v_jd`` (scaled by ``1/σ_j`` and
    ``S_j⁻¹``, so that ``ω_jd = L_j v_jd``); see `ik_forward`."""
    rot, cz, sz = _euler_rows(angles)
    lr, sc = model.local_rest, model.scales
    rs = rot * sc[:, None, :3]  # R_x R_y R_z S_j
    g = jnp.concatenate([_mm_unrolled(lr[:, :, :3], rs), lr[:, :, 3:]], axis=2)  # (J, 4, 4)
    eye = np.eye(4, dtype=g.dtype)[None]  # a literal: no kernel builds it
    for step in range(model.hops.shape[0]):
        # (2, J, 4, 4), index J: none; "clip" (in range anyway): no negative-index wrap
        up = jnp.take(jnp.concatenate([g, eye]), model.hops[step], axis=0, mode="clip")
        g = _mm_reduce(_mm_unrolled(up[1], up[0]), g)
    # ω_jd = L_j S_j⁻¹ v_jd / σ_j with v_jx = E_jᵀ e_x, v_jy = R_zᵀ e_y, v_jz = e_z
    zero = jnp.zeros_like(cz)
    v = jnp.stack(
        [rot[:, 0, :], jnp.stack([sz, cz, zero], -1), jnp.stack([zero, zero, zero + 1], -1)], 1
    )
    return g, v * (sc[:, 3:] / sc[:, :3])[:, None, :]


def ik_frames(model: IKModel, angles: Float[Array, "joints 3"]) -> tuple[Array, Array]:
    """Posed global transforms ``G_j`` (``(J, 4, 4)``, without the world translation) and
    the unit world Euler axes ``ω_jd`` (``(J, dof, xyz)``), the axes as one elementwise
    kernel (no batched product: the Levenberg–Marquardt kernel, where every kernel launch
    counts)."""
    g, v = _global_frames(model, angles)
    axes = sum(g[:, None, :3, c] * v[:, :, c : c + 1] for c in range(3))
    return g, axes


@checked
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
    g, v = _global_frames(model, pose.angles)
    o = g[:, :3, 3] + pose.translation[None, :]
    lin = g[:, :3, :3]
    v = jnp.concatenate([v, jnp.zeros_like(v[..., :1])], axis=-1)
    axes = jnp.einsum("jrc,jdc->jdr", g, v)[..., :3]  # (J, dof, xyz)
    gm = g[model.marker_joints][..., :3, :]  # (K, N, 3, 4)
    uw = model.marker_skin
    q = jnp.einsum("knrc,knc->knr", gm, uw) + uw[..., 3:] * pose.translation[None, None, :]
    return IKForward(o, axes, lin, q, q.sum(axis=1))


@checked
def ik_markers(model: IKModel, pose: Pose) -> Float[Array, "markers 3"]:
    """Marker positions ``p_k(θ)``."""
    return ik_forward(model, pose).markers


@checked
def ik_residuals(
    model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> Float[Array, "markers 3"]:
    """``δ_k = p_k(θ) − t_k``."""
    return ik_markers(model, pose) - targets


@checked
def ik_objective(
    model: IKModel, pose: Pose, targets: Float[Array, "markers 3"]
) -> Float[Array, ""]:
    """``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` (the paper's eq. (1)/(7))."""
    d = ik_residuals(model, pose, targets)
    return jnp.sum(d * d)
