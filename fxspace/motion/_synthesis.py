"""Decoupled parametric synthesis (Ha & Han): two parametric spaces, one pure step per
animation frame with the clocks of eqs. (1)–(3) and the §3.2 re-placement of the upper
space's samples when the lower-body parameter changes.

Every public function here is jitted (eager calls compile once per shape, then run fast);
they trace inside other jitted code as usual.

The upper parameter is expressed in the character's *root frame*: relative to the root's
ground position (x, z; heights kept) and rotated into its heading (yaw) frame, as the paper
stores ``ṗ_i`` ("translated and rotated so that the root frame coincides with the origin").
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import checked
from fxspace.errors import FxspaceError
from fxspace.motion._blend import ExampleSet, blend_pose, knn_blend_weights, sample_blend_weights
from fxspace.motion._fk import fk_arrays
from fxspace.motion._horn import absolute_orientation, absolute_rotation, apply_rigid
from fxspace.motion._joint_guard import example_joint_steps
from fxspace.motion._splice import heading_quat, heck_splice, splice_pose, torso_joints
from fxspace.motion._synth_clocks import _advance, check_step_controls
from fxspace.motion._synth_types import Pose, SynthesisSpaces, SynthState
from fxspace.motion._timewarp import invert_curve
from fxspace.rotations import quat_conj, quat_rotate

__all__ = [
    "build_spaces",
    "init_state",
    "synthesize_step",
    "synthesize",
    "replace_samples",
    "exact_upper_params",
    "upper_param_of",
    "lower_param_of",
]


@checked
def splice_frame(sp: SynthesisSpaces, qL: Float[Array, "J 4"], qU: Float[Array, "J 4"]):
    """The upper body of ``qU`` spliced on the lower body of ``qL`` with the spaces' splice
    (``sp.splice``: ``"heck"`` → `heck_splice`, ``"heading"`` → `splice_pose`)."""
    mask = jnp.asarray(sp.mask)
    if sp.splice == "heck":
        return heck_splice(
            qL, qU, sp.parents, sp.offsets, mask, sp.spine, sp.torso, sp.posture_transfer
        )
    return splice_pose(qL, qU, mask, sp.spine, sp.posture_transfer)


def _fk1(sp: SynthesisSpaces, root, q):
    return fk_arrays(sp.parents, sp.offsets, root[None], q[None])[0][0]


def _to_root_frame(x, X_root, q_root):
    rel = (x - X_root) * jnp.asarray([1.0, 0.0, 1.0]) + x * jnp.asarray([0.0, 1.0, 0.0])
    return quat_rotate(quat_conj(heading_quat(q_root)), rel)


@checked
@jax.jit
def lower_param_of(sp: SynthesisSpaces, w_lower: Float[Array, " EL"]) -> Float[Array, " d"]:
    """The lower parameter of a lower blend: joint ``lower_joint``'s world position (dims
    ``lower_dims``) at reference time ``lower_time`` (start-aligned clips)."""
    q, r = blend_pose(sp.lower, w_lower, sp.lower_time)
    return _fk1(sp, r, q)[sp.lower_joint][jnp.asarray(sp.lower_dims)]


@checked
@jax.jit
def upper_param_of(
    sp: SynthesisSpaces, w_lower: Float[Array, " EL"], w_upper: Float[Array, " EU"]
) -> Float[Array, " 3"]:
    """The *real* upper parameter (§3.2) of upper blend ``w_upper`` spliced onto lower blend
    ``w_lower``: joint ``upper_joint`` in the root frame when the upper clock is at
    ``upper_time`` — the lower clock is then at ``λ⁻¹(upper_time)`` (eq. 3)."""
    t_l = invert_curve(sp.lam, sp.upper_time)
    qL, rL = blend_pose(sp.lower, w_lower, t_l)
    qU, _ = blend_pose(sp.upper, w_upper, sp.upper_time)
    q = splice_frame(sp, qL, qU)
    X = _fk1(sp, rL, q)
    return _to_root_frame(X[sp.upper_joint], X[0], q[0])


@checked
@jax.jit
def exact_upper_params(sp: SynthesisSpaces, w_lower: Float[Array, " EL"]) -> Float[Array, "S 3"]:
    """Re-sampling from scratch (the exact, slow route the paper rejects): the real
    parameter of every upper sample for lower blend ``w_lower``."""
    return jax.vmap(lambda w: upper_param_of(sp, w_lower, w))(sp.upper_weights)


@checked
@jax.jit
def replace_samples(sp: SynthesisSpaces, w_lower: Float[Array, " EL"]) -> Float[Array, "S 3"]:
    """§3.2 re-placement: the real parameters ``p_1..p_k`` of the first ``k = k_replace``
    samples for the new lower blend (root frame), then, as printed, the rotation ``R``
    about the root that takes the stored ``ṗ_1..ṗ_k`` closest to them (Horn, least
    squares), applied to all ``n`` stored ``ṗ_i`` (``sp.replace == "rotation"``, the
    default); ``"rigid"`` fits a translation too. O(k) splices + O(n)."""
    k = sp.k_replace
    real = jax.vmap(lambda w: upper_param_of(sp, w_lower, w))(sp.upper_weights[:k])
    if sp.replace == "rigid":
        return apply_rigid(absolute_orientation(sp.upper_params[:k], real), sp.upper_params)
    R = absolute_rotation(sp.upper_params[:k], real)
    return sp.upper_params @ R.T


def _lower_weights(sp, lower_param):
    return knn_blend_weights(lower_param, sp.lower_params, sp.lower_weights, sp.knn_k).weights


@checked
@jax.jit
def init_state(sp: SynthesisSpaces, lower_param: Float[Array, " d"]) -> SynthState:
    """Clocks at the start (``T_L = 0``, ``T_U = λ(0)``) and the upper samples re-placed
    for ``lower_param``."""
    lower_param = jnp.asarray(lower_param, sp.lam.dtype)
    wL = _lower_weights(sp, lower_param)
    params = replace_samples(sp, wL) if sp.upper_joint >= 0 else sp.upper_params
    z = jnp.zeros((), sp.lam.dtype)
    return SynthState(z, sp.lam[0] + z, lower_param, params, wL)


def _blends(sp: SynthesisSpaces, state: SynthState, upper_param, lower_param, wL=None):
    """Steps 1–3 of `synthesize_step`: the lower blend (``wL`` given: used as is), the
    (re-placed) upper samples and the upper blend; NaN weights when a parameter is not
    finite (never a plausible blend)."""
    dtype = sp.lam.dtype
    lower_param = jnp.asarray(lower_param, dtype)
    upper_param = jnp.asarray(upper_param, dtype)
    wL = _lower_weights(sp, lower_param) if wL is None else wL
    if sp.upper_joint >= 0:
        changed = jnp.any(lower_param != state.lower_param)
        params = jax.lax.cond(changed, lambda: replace_samples(sp, wL), lambda: state.upper_params)
        wU = knn_blend_weights(upper_param, params, sp.upper_weights, sp.knn_k).weights
    else:
        params = state.upper_params
        wU = jnp.maximum(upper_param, 0.0)
        wU = wU / jnp.maximum(jnp.sum(wU), 1e-12)
    bad = ~(jnp.all(jnp.isfinite(upper_param)) & jnp.all(jnp.isfinite(lower_param)))
    nan = jnp.asarray(jnp.nan, dtype)
    return jnp.where(bad, nan, wL), jnp.where(bad, nan, wU), params, lower_param


def _spliced(sp: SynthesisSpaces, wL, wU, t_lower, t_upper):
    """Step 4: both blends at their clocks (every example at ``C_i(T)``), spliced."""
    qL, rL = blend_pose(sp.lower, wL, t_lower)
    qU, _ = blend_pose(sp.upper, wU, t_upper)
    return splice_frame(sp, qL, qU), rL


@jax.jit
def _synthesize_step(spaces, state, upper_param, lower_param, alpha, dt):
    dtype = spaces.lam.dtype
    alpha = jnp.asarray(alpha, dtype)
    wL, wU, params, lower_param = _blends(spaces, state, upper_param, lower_param)
    q, rL = _spliced(spaces, wL, wU, state.t_lower, state.t_upper)
    ok = jnp.isfinite(alpha) & jnp.isfinite(dt) & (alpha >= 0) & (alpha <= 1) & (dt >= 0)
    q, rL = jnp.where(ok, q, jnp.nan), jnp.where(ok, rL, jnp.nan)
    tl, tu, _ = _advance(spaces, state, wL, wU, alpha, dt, wrap=False)
    return SynthState(tl, tu, lower_param, params, wL), Pose(q, rL)


@checked
def synthesize_step(
    spaces: SynthesisSpaces,
    state: SynthState,
    upper_param: Float[Array, " p"],
    lower_param: Float[Array, " d"],
    alpha: float | Float[Array, ""] = 0.5,
    dt: float | Float[Array, ""] = 1.0,
) -> tuple[SynthState, Pose]:
    """One animation frame of decoupled synthesis (Ha & Han §3): pure, jittable, runs under
    ``lax.scan``; both parameters may change every frame.

    1. Lower blend ``w_L`` by k-NN interpolation of ``lower_param`` over the lower samples.
    2. If ``lower_param`` differs from the one of the last re-placement, the upper samples
       are re-placed (§3.2, `replace_samples`; ``lax.cond``, so only then).
    3. Upper blend ``w_U``: k-NN of ``upper_param`` (root frame) over the re-placed samples —
       or, for a space without parameterisation (``upper_joint = -1``), ``upper_param`` is
       the weight vector itself (normalised).
    4. The pose at the current clocks: both blends (every example at ``C_i(T)``), spliced.
    5. Clocks: eq. (1) for each set, then eqs. (2)–(3) with ``alpha`` (`align_clocks`);
       ``T_L`` stops at the lower reference clip's end (`locomotion_step` wraps it instead).

    **Arguments:** ``alpha`` in ``[0, 1]`` and ``dt >= 0`` (reference frames per output
    frame); other values raise `FxspaceError` (when concrete; a traced bad value, or a NaN
    parameter, gives a NaN pose — never a plausible finite one).

    **Returns:** ``(state, pose)`` with ``pose`` the frame at the *incoming* clocks.

    Example: ``state = init_state(sp, p_L)``; ``state, pose = synthesize_step(sp, state,
    p_U, p_L, 0.5, 1.0)``.
    """
    check_step_controls(alpha, dt)
    return _synthesize_step(spaces, state, upper_param, lower_param, alpha, dt)


@checked
def synthesize(
    spaces: SynthesisSpaces,
    upper_params: Float[Array, "F p"],
    lower_params: Float[Array, "F d"],
    alpha: float | Float[Array, " F"] = 0.5,
    dt: float = 1.0,
) -> tuple[SynthState, Pose, Float[Array, "F 2"]]:
    """``F`` frames by ``lax.scan`` of `synthesize_step` (parameters per frame; the clocks
    stop at the lower reference clip's end — `locomotion` walks on instead).

    **Returns:** ``(final_state, poses, clocks)`` — ``poses`` stacked ``(F, J, 4)`` /
    ``(F, 3)``, ``clocks`` ``(F, 2)`` the ``(T_L, T_U)`` of each output frame."""
    if not isinstance(alpha, jax.core.Tracer) and np.ndim(alpha) == 0:
        check_step_controls(alpha, dt)
    return _synthesize(spaces, upper_params, lower_params, alpha, dt)


@jax.jit
def _synthesize(spaces, upper_params, lower_params, alpha, dt):
    F = upper_params.shape[0]
    alphas = jnp.broadcast_to(jnp.asarray(alpha, spaces.lam.dtype), (F,))
    state = init_state(spaces, lower_params[0])

    def body(s, inp):
        pu, pl, a = inp
        s2, pose = _synthesize_step(spaces, s, pu, pl, a, dt)
        return s2, (pose, jnp.stack([s.t_lower, s.t_upper]))

    final, (poses, clocks) = jax.lax.scan(body, state, (upper_params, lower_params, alphas))
    return final, poses, clocks


@checked
def build_spaces(
    lower: ExampleSet,
    upper: ExampleSet,
    lam: Float[Array, " NL"],
    parents: tuple[int, ...],
    offsets: Float[Array, "J 3"],
    *,
    mask,
    spine: int,
    lower_joint: int,
    lower_dims: tuple[int, ...],
    lower_time: float,
    upper_joint: int,
    upper_time: float,
    key: Array,
    n_samples: int = 1000,
    knn_k: int = 6,
    k_replace: int = 10,
    posture_transfer: float = 1.0,
    splice: str = "heck",
    concentration: float = 0.5,
    max_active: int = 3,
    min_slope: float = 0.05,
    replace: str = "rotation",
    max_clock_rate: float | int = 1.0,  # not ``float``: ``inf`` (eqs. 2–3 as printed) is valid
) -> SynthesisSpaces:
    """Sample both parameter spaces (Kovar & Gleicher 2004: ``n_samples`` random sparse
    blends, the examples first) and evaluate their parameters in one vmapped call each: the
    lower parameter (`lower_param_of`) and the upper one in the root frame, spliced
    onto the first lower example (``ṗ_i``, §3.2). ``upper_joint = -1`` builds an upper space
    without parameterisation (weights set by the user). ``k_replace`` (§3.2's ``k``, 8–12 in
    the paper) must not exceed the number of upper samples."""
    kL, kU = jax.random.split(key)
    EL, EU = lower.warps.shape[0], upper.warps.shape[0]
    WL = sample_blend_weights(kL, EL, max(n_samples, EL), concentration, max_active)
    WU = sample_blend_weights(kU, EU, max(n_samples, EU), concentration, max_active)
    if splice not in ("heck", "heading"):
        raise ValueError(f"splice must be 'heck' or 'heading', got {splice!r}")
    if replace not in ("rotation", "rigid"):
        raise ValueError(
            f"replace must be 'rotation' (§3.2 as printed) or 'rigid', got {replace!r}"
        )
    max_clock_rate = _check_clock_rate(max_clock_rate)
    if upper_joint >= 0 and not 3 <= k_replace <= WU.shape[0]:
        raise ValueError(f"k_replace must lie in [3, {WU.shape[0]}], got {k_replace}")
    dtype = jnp.result_type(float)
    w0 = jnp.zeros(EL, dtype).at[0].set(1.0)
    sp = SynthesisSpaces(
        lower=lower,
        upper=upper,
        lam=jnp.asarray(lam, dtype),
        offsets=jnp.asarray(offsets, dtype),
        lower_weights=WL,
        lower_params=jnp.zeros((WL.shape[0], len(lower_dims)), dtype),
        upper_weights=WU,
        upper_params=jnp.zeros((WU.shape[0], 3), dtype),
        lower_w0=w0,
        lower_time=jnp.asarray(lower_time, dtype),
        upper_time=jnp.asarray(upper_time, dtype),
        posture_transfer=jnp.asarray(posture_transfer, dtype),
        joint_steps=jnp.asarray(
            example_joint_steps(lower, upper, tuple(int(p) for p in parents), offsets), dtype
        ),
        parents=tuple(int(p) for p in parents),
        mask=tuple(bool(b) for b in np.asarray(mask)),
        spine=int(spine),
        lower_joint=int(lower_joint),
        lower_dims=tuple(int(d) for d in lower_dims),
        upper_joint=int(upper_joint),
        k_replace=int(k_replace),
        knn_k=int(knn_k),
        min_slope=float(min_slope),
        max_clock_rate=float(max_clock_rate),
        splice=splice,
        torso=torso_joints(tuple(int(p) for p in parents), mask, int(spine)),
        replace=replace,
    )
    return _sample_params(sp)


def _check_clock_rate(r) -> float:
    """``max_clock_rate``: a real number > 0; ``inf`` (eqs. 2–3 as printed) is accepted."""
    if isinstance(r, bool) or not isinstance(r, int | float | np.floating | np.integer):
        raise FxspaceError(f"max_clock_rate must be a number > 0 (inf: eqs. 2–3 as printed), "
                           f"got {r!r}")  # fmt: skip
    if not float(r) > 0:  # NaN too
        raise FxspaceError(f"max_clock_rate must be > 0 (inf: eqs. 2–3 as printed), got {r!r}")
    return float(r)


@jax.jit
def _sample_params(sp: SynthesisSpaces) -> SynthesisSpaces:
    PL = jax.vmap(lambda w: lower_param_of(sp, w))(sp.lower_weights)
    PU = exact_upper_params(sp, sp.lower_w0) if sp.upper_joint >= 0 else sp.upper_params
    return dataclasses.replace(sp, lower_params=PL, upper_params=PU)
