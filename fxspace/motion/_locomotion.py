"""Continuous locomotion on top of decoupled synthesis (the "next step" Ha & Han name in
their conclusion): the lower-body clock wraps at the end of the reference cycle and the
root's ground displacement and heading are *integrated*, so the walker never jumps back;
a turning parameter (heading change, degrees per second) measured on the lower samples
steers it; a scripted session runs the whole controller without a browser.

The pose a step returns is in the world: the root's ground position and heading come from
the integrated state, its height and tilt from the blend. The displacement between two
reference times is taken from the *current* lower blend at both ends, so a parameter
change never moves the root by itself (no jump), and it is expressed in the blend's own
heading frame (a blend that turns, turns the walker).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._compile_cache import cached_executable
from fxspace._validate import check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.motion._blend import blend_pose, blend_quaternions, pose_at, warp_times
from fxspace.motion._fk import fk_arrays
from fxspace.motion._synthesis import (
    Pose,
    SynthesisSpaces,
    SynthState,
    _advance,
    _blends,
    _fk1,
    _lower_weights,
    check_step_controls,
    init_state,
    splice_frame,
)
from fxspace.rotations import (
    quat_conj,
    quat_from_axis_angle,
    quat_mul,
    quat_nlerp,
    quat_normalize,
    quat_rotate,
)

__all__ = [
    "LocomotionState",
    "TurnTable",
    "init_locomotion",
    "locomotion_step",
    "locomotion_stepper",
    "locomotion",
    "turn_table",
    "turn_to_lower_param",
    "heading_angle",
]

_UP = (0.0, 1.0, 0.0)
#: time constant (output frames) of the decay of the wrap offset
WRAP_BLEND_FRAMES = 6.0
#: time constant (output frames) of the low-pass on the lower blend weights
WEIGHT_SMOOTH_FRAMES = 8.0
#: bisection halvings of the joint-speed guard's share of a frame (`locomotion_step`)
JOINT_GUARD_STEPS = 10
#: the share of the examples' joint steps the guard aims a frame's predicted step at: the
#: next frame's controls, which it cannot see, move the blend by a few per cent of them
#: (at most 8 % measured on the shipped walks)
JOINT_GUARD_TARGET = 0.95


class LocomotionState(NamedTuple):
    """``synth``: the clocks and re-placed samples (`SynthState`); ``position`` ``(3,)``:
    the root's ground position (x, 0, z) in the world; ``yaw``: the walker's heading in the
    world (radians about +Y; 0 faces +Z); ``cycles``: lower cycles completed."""

    synth: SynthState
    position: Float[Array, " 3"]
    yaw: Float[Array, ""]
    cycles: Float[Array, ""]
    offset: Float[Array, "J 4"] | None = None
    height_offset: Float[Array, ""] | None = None
    upper_weights: Float[Array, " EU"] | None = None


@checked
def heading_angle(q: Float[Array, "... 4"]) -> Float[Array, ...]:
    """Yaw (radians about +Y, 0 = facing +Z, positive = turning left) of a root orientation."""
    q = jnp.asarray(q)
    f = quat_rotate(q, jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0], q.dtype), q.shape[:-1] + (3,)))
    return jnp.arctan2(f[..., 0], f[..., 2])


def _yaw_quat(a):
    a = jnp.asarray(a)
    return quat_from_axis_angle(jnp.broadcast_to(jnp.asarray(_UP, a.dtype), a.shape + (3,)), a)


def _wrap_angle(a):
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def _example_frames(sp: SynthesisSpaces, t):
    """Every lower example at its registered time ``C_i(t)``: rotations ``(E, J, 4)``,
    roots ``(E, 3)`` and headings ``(E,)``."""
    q, r = pose_at(sp.lower, warp_times(sp.lower.warps, t))
    return q, r, heading_angle(q[:, 0])


def _lower_local(sp: SynthesisSpaces, w, t):
    """The lower blend at reference time ``t`` with each example's root *heading removed*
    before blending (turning examples face different ways late in the cycle: their root
    rotations are blended as tilts, the heading is integrated separately)."""
    q, r, yaw = _example_frames(sp, t)
    tilt = quat_mul(_yaw_quat(-yaw), q[:, 0])
    qb = blend_quaternions(q.at[:, 0].set(tilt), w)
    return qb, jnp.einsum("e,ea->a", w, r)


def _spliced_local(sp: SynthesisSpaces, wL, wU, t_lower, t_upper):
    """`_lower_local` under the upper blend, spliced (root = the blend's tilt)."""
    qL, rL = _lower_local(sp, wL, t_lower)
    qU, _ = blend_pose(sp.upper, wU, t_upper)
    return splice_frame(sp, qL, qU), rL


def _delta(sp: SynthesisSpaces, w, ta, tb):
    """Ground displacement (in the walker's heading frame) and heading change of the lower
    blend ``w`` from reference time ``ta`` to ``tb``: each example's own displacement in its
    own heading frame at ``ta``, and its own heading change, blended with ``w`` (blending
    velocities, not positions: turning examples do not cancel)."""
    qa, ra, ya = _example_frames(sp, ta)
    qb, rb, yb = _example_frames(sp, tb)
    flat = jnp.asarray([[1.0, 0.0, 1.0]], rb.dtype)
    d = quat_rotate(_yaw_quat(-ya), (rb - ra) * flat)
    return jnp.einsum("e,ea->a", w, d), jnp.einsum("e,e->", w, _wrap_angle(yb - ya))


def _move(position, yaw, d, dy):
    return position + quat_rotate(_yaw_quat(yaw), d), yaw + dy


@checked
def init_locomotion(
    sp: SynthesisSpaces, lower_param: Float[Array, " d"], position=None, yaw=0.0
) -> LocomotionState:
    """The walker at the start of the cycle, at ``position`` (default the origin), facing
    ``yaw`` (radians about +Y)."""
    dtype = sp.lam.dtype
    pos = jnp.zeros(3, dtype) if position is None else jnp.asarray(position, dtype)
    args = (sp, jnp.asarray(lower_param, dtype), pos, jnp.asarray(yaw, dtype))
    # one program (not hundreds of eager ops), kept on disk for the next process
    return cached_executable(_init_locomotion, *args)(*args)


@jax.jit
def _init_locomotion(sp, lower_param, position, yaw):
    s = init_state(sp, lower_param)
    dtype = sp.lam.dtype
    pos = position * jnp.asarray([1.0, 0.0, 1.0], dtype)
    J = len(sp.parents)
    ident = jnp.zeros((J, 4), dtype).at[:, 0].set(1.0)
    z = jnp.zeros((), dtype)
    wU = jnp.zeros(sp.upper.warps.shape[0], dtype)  # none yet: the first step takes its own
    return LocomotionState(s, pos, yaw, z, ident, z, wU)


def _wrap_offsets(sp, state, wL, wU, decay):
    """The wrap offset and height offset after one frame: decayed, and (the second pair,
    used when the lower clock wraps) decayed then composed with the end-of-cycle pose
    relative to the start."""
    dtype = sp.lam.dtype
    ident = jnp.zeros_like(state.offset).at[:, 0].set(1.0)
    off = quat_nlerp(ident, state.offset, jnp.full(state.offset.shape[:1], decay, dtype))
    h = state.height_offset * decay
    end = jnp.asarray(sp.lam.shape[0] - 1.0, dtype)
    qe, re = _spliced_local(sp, wL, wU, end, sp.lam[-1])
    qs, rs = _spliced_local(sp, wL, wU, jnp.zeros((), dtype), sp.lam[0])
    new = quat_mul(qe, quat_conj(qs)).at[0].set(ident[0])
    return (off, h), (quat_mul(off, new), h + re[1] - rs[1])


def _world_pose(sp, synth, position, yaw, offset, height_offset, wL, wU):
    """The output frame of a walker state: the spliced blends at its clocks under the
    wrap offset, the root at the integrated ground position and heading with the blend's
    height (plus the height offset) and tilt."""
    up = jnp.asarray(_UP, sp.lam.dtype)
    q, rL = _spliced_local(sp, wL, wU, synth.t_lower, synth.t_upper)
    q = quat_normalize(quat_mul(offset, q))
    root_q = quat_mul(_yaw_quat(yaw - heading_angle(q[0])), q[0])
    # concatenate, not ``q.at[0].set``: XLA on CPU (jaxlib 0.10.2) miscompiles that scatter
    # of a quaternion product when forward kinematics follows in the same program (the
    # joint guard's, `_joint_guard`): joints off by decimetres
    q = jnp.concatenate([root_q[None], q[1:]], axis=0)
    return q, position + (rL + up * height_offset) * up


def _walk_on(sp, state, wL, wU, alpha, dt, offsets):
    """One frame of ``dt``: the clocks (eqs. 1–3, wrapping), the ground position and heading
    integrated from the lower blend (across a wrap: end of cycle, then start), and the
    wrap offsets of `_wrap_offsets`. Returns ``(t_lower, t_upper, wrapped, position, yaw,
    offset, height_offset)``."""
    s = state.synth
    tl, tu, wrapped = _advance(sp, s, wL, wU, alpha, dt, wrap=True)
    end = jnp.asarray(sp.lam.shape[0] - 1.0, sp.lam.dtype)
    d1, y1 = _delta(sp, wL, s.t_lower, jnp.where(wrapped, end, tl))
    d2, y2 = _delta(sp, wL, jnp.where(wrapped, 0.0, tl), tl)
    pos, yaw = _move(state.position, state.yaw, d1, y1)
    pos, yaw = _move(pos, yaw, d2, y2)
    (off0, h0), (off1, h1) = offsets
    off, h = jnp.where(wrapped, off1, off0), jnp.where(wrapped, h1, h0)
    return tl, tu, wrapped, pos, _wrap_angle(yaw), off, h


def _joint_guard(sp, state, pose, w_now, w_next, alpha, dt, offsets):
    """The joint-speed half of the bound on the clocks: the largest share ``c`` of this
    frame's ``dt`` (bisection, `JOINT_GUARD_STEPS` halvings) such that the next frame —
    the clocks advanced by ``c · dt``, the blend weights ``w_next`` the low-pass is heading
    for — moves no joint further from ``pose`` than `JOINT_GUARD_TARGET` × ``max_clock_rate
    × joint_steps × dt`` (the fastest captured clip's same joint). ``1`` where the full
    step already keeps every joint inside; where the weights alone (``c = 0``) would pass
    it, ``c`` only keeps the clocks from adding to that."""
    dtype = sp.lam.dtype
    limit = JOINT_GUARD_TARGET * sp.max_clock_rate * sp.joint_steps * dt
    X0 = _fk1(sp, pose.root, pose.rotations)

    def excess(c):
        tl, tu, _, pos, yaw, off, h = _walk_on(sp, state, *w_now, alpha, c * dt, offsets)
        synth = state.synth._replace(t_lower=tl, t_upper=tu)
        q, r = _world_pose(sp, synth, pos, yaw, off, h, *w_next)
        step = jnp.linalg.norm(_fk1(sp, r, q) - X0, axis=-1)
        return jnp.max(step / jnp.maximum(limit, 1e-12))

    def body(carry):  # one call site of `excess` (one copy of the pose in the program)
        i, lo, hi, allowed, _ = carry
        c = jnp.where(i == 0, 1.0, jnp.where(i == 1, 0.0, 0.5 * (lo + hi))).astype(dtype)
        e = excess(c)
        # i = 0: the full step, done if inside; i = 1: what the weights alone do; then halve
        allowed = jnp.where(i == 1, jnp.maximum(1.0, e), allowed)
        ok = e <= allowed
        lo = jnp.where(i == 0, jnp.where(ok, 1.0, 0.0), jnp.where((i >= 2) & ok, c, lo))
        hi = jnp.where((i >= 2) & ~ok, c, hi)
        return i + 1, lo.astype(dtype), hi, allowed, (i == 0) & ok

    one, zero = jnp.ones((), dtype), jnp.zeros((), dtype)
    carry = (jnp.zeros((), jnp.int32), zero, one, one, jnp.zeros((), bool))
    carry = jax.lax.while_loop(lambda c: ~c[4] & (c[0] < JOINT_GUARD_STEPS + 2), body, carry)
    return carry[1]


@jax.jit
def _locomotion_step(sp, state, upper_param, lower_param, alpha, dt):
    dtype = sp.lam.dtype
    s = state.synth
    alpha = jnp.asarray(alpha, dtype)
    # k-NN weights over dense random samples change abruptly as the parameter moves
    # (different blends reach the same foot position): low-pass them (weights stay convex)
    w_raw = _lower_weights(sp, jnp.asarray(lower_param, dtype))
    beta = 1.0 - np.exp(-1.0 / WEIGHT_SMOOTH_FRAMES)
    wL = s.lower_weights + beta * (w_raw - s.lower_weights)
    wL, wU, params, lower_param = _blends(sp, s, upper_param, lower_param, wL)
    wU_next = wU  # what the next frame's weights head for (the guard's prediction)
    if sp.upper_joint >= 0:  # the upper k-NN weights jump the same way
        prev, wU_raw = state.upper_weights, wU
        wU = jnp.where(jnp.sum(prev) > 0, prev + beta * (wU_raw - prev), wU_raw)
        wU_next = wU + beta * (wU_raw - wU)
    rot, root = _world_pose(sp, s, state.position, state.yaw, state.offset,
                            state.height_offset, wL, wU)  # fmt: skip
    ok = jnp.isfinite(alpha) & jnp.isfinite(dt) & (alpha >= 0) & (alpha <= 1) & (dt >= 0)
    pose = Pose(jnp.where(ok, rot, jnp.nan), jnp.where(ok, root, jnp.nan))
    offsets = _wrap_offsets(sp, state, wL, wU, np.exp(-1.0 / WRAP_BLEND_FRAMES))
    if sp.aligned and sp.max_clock_rate != float("inf"):  # the bound's joint-speed half
        # the next frame's lower weights: the low-pass heading for the parameter
        # extrapolated one frame (the controls move smoothly)
        w_ahead = _lower_weights(sp, 2.0 * lower_param - s.lower_param)
        w_next = (wL + beta * (w_ahead - wL), wU_next)
        dt = dt * _joint_guard(sp, state, pose, (wL, wU), w_next, alpha, dt, offsets)
    tl, tu, wrapped, pos, yaw, off, h = _walk_on(sp, state, wL, wU, alpha, dt, offsets)
    synth = SynthState(tl, tu, lower_param, params, wL)
    return LocomotionState(synth, pos, yaw, state.cycles + wrapped, off, h, wU), pose


@checked
def locomotion_step(
    sp: SynthesisSpaces,
    state: LocomotionState,
    upper_param: Float[Array, " p"],
    lower_param: Float[Array, " d"],
    alpha: float | Float[Array, ""] = 0.5,
    dt: float | Float[Array, ""] = 1.0,
) -> tuple[LocomotionState, Pose]:
    """One frame of continuous decoupled synthesis: `synthesize_step`'s blends and splice,
    the clocks of eqs. (1)–(3) with the lower clock *wrapping* at the end of the reference
    cycle (``T_L ← T_L − (N−1)``, ``T_U ← T_U − (λ(N−1) − λ(0))`` before eqs. 2–3, so the
    upper clock wraps consistently), and the root's ground displacement and heading change
    integrated from the current lower blend (both ends of a step with the same weights;
    across a wrap, end-of-cycle then start-of-cycle). The lower k-NN weights are low-passed
    (time constant `WEIGHT_SMOOTH_FRAMES`), and so are the upper ones of a parametric upper
    space: over dense random samples they jump between very different blends as the
    parameter moves. With the default bound (finite ``sp.max_clock_rate``, clocks aligned)
    a frame whose step would move a joint further than the fastest captured clip's same
    joint (``sp.joint_steps``) advances its clocks by a shorter share of ``dt``
    (`_joint_guard`); ``max_clock_rate = inf`` is eqs. 2–3 as printed, unguarded.

    **Returns:** ``(state, pose)``; ``pose`` in the world (root translation = integrated
    ground position + the blend's root height; root rotation = world heading ⊗ the blend's
    tilt). A NaN parameter gives a NaN pose; ``alpha`` outside ``[0, 1]`` or ``dt < 0``
    raise `FxspaceError`.
    """
    check_step_controls(alpha, dt)
    return _locomotion_step(sp, state, upper_param, lower_param, alpha, dt)


@checked
def locomotion_stepper(
    sp: SynthesisSpaces,
    state: LocomotionState,
    upper_param: Float[Array, " p"],
    lower_param: Float[Array, " d"],
):
    """`locomotion_step` for this set-up, compiled ahead of time: the function an
    interactive controller calls every frame.

    The compiled step is kept on disk beside fxspace's compilation cache
    (``FXSPACE_COMPILE_CACHE``; not when the cache is off), so a new process that opens
    the same set-up skips tracing and lowering the step as well as compiling it. The
    example arguments give the shapes (``state`` from `init_locomotion`, the parameters of
    the set-up's dimensions).

    **Returns:** ``step(state, upper_param, lower_param, alpha=0.5, dt=1.0) -> (state,
    pose)``, the same contract as `locomotion_step` (``alpha`` / ``dt`` checked; other
    shapes fall back to the jitted step).
    """
    dtype = sp.lam.dtype
    ex = (sp, state, jnp.asarray(upper_param, dtype), jnp.asarray(lower_param, dtype),
          np.asarray(0.5, dtype), np.asarray(1.0, dtype))  # fmt: skip
    exe = cached_executable(_locomotion_step, *ex)

    def step(state, upper_param, lower_param, alpha=0.5, dt=1.0):
        check_step_controls(alpha, dt)
        return exe(sp, state, jnp.asarray(upper_param, dtype), jnp.asarray(lower_param, dtype),
                   np.asarray(alpha, dtype), np.asarray(dt, dtype))  # fmt: skip

    step.source = exe.source
    return step


@checked
@jax.jit
def locomotion(
    sp: SynthesisSpaces,
    state: LocomotionState,
    upper_params: Float[Array, "F p"],
    lower_params: Float[Array, "F d"],
    alphas: Float[Array, " F"],
    dt: float | Float[Array, ""] = 1.0,
) -> tuple[LocomotionState, Pose]:
    """``F`` frames of `locomotion_step` by ``lax.scan`` (parameters per frame)."""

    def body(st, inp):
        pu, pl, a = inp
        return _locomotion_step(sp, st, pu, pl, a, dt)

    return jax.lax.scan(body, state, (upper_params, lower_params, alphas))


# ---------------------------------------------------------------------------- steering
@dataclasses.dataclass(frozen=True)
class TurnTable:
    """Turning rate → lower parameter: ``turn`` ``(G,)`` degrees per second (positive = to
    the left), ``params`` ``(G, d)`` the lower parameter that walks at that rate; ``low`` /
    ``high`` the range spanned by the example clips (straight walks and turns)."""

    turn: np.ndarray
    params: np.ndarray
    low: float
    high: float


jax.tree_util.register_dataclass(
    TurnTable, data_fields=["turn", "params"], meta_fields=["low", "high"]
)


def _sample_turn_rates(sp: SynthesisSpaces, rate: float) -> np.ndarray:
    """Heading change of every lower sample over the reference cycle, degrees per second
    (the blend's duration: its weighted example lengths)."""
    args = (sp, jnp.asarray(rate, sp.lam.dtype))
    return np.asarray(cached_executable(_turn_rates, *args)(*args), np.float64)


@jax.jit
def _turn_rates(sp, rate):
    end = sp.lam.shape[0] - 1.0

    def one(w):
        _, dyaw = _delta(sp, w, jnp.asarray(0.0, sp.lam.dtype), jnp.asarray(end, sp.lam.dtype))
        dur = jnp.sum(w * (sp.lower.warps[:, -1] - sp.lower.warps[:, 0])) / rate
        return jnp.degrees(dyaw) / jnp.maximum(dur, 1e-6)

    return jax.vmap(one)(sp.lower_weights)


@checked
def turn_table(sp: SynthesisSpaces, rate: float, n_grid: int = 101) -> TurnTable:
    """Steering for a walk set-up: the turning rate of every lower sample (heading change
    over the reference cycle, °/s), and a smooth curve (Gaussian kernel regression over the
    samples, bandwidth 1/10 of the range) from turning rate to the lower parameter. The
    range is the one the example clips span (walk-turn-left/right and straight walks)."""
    rates = _sample_turn_rates(sp, float(rate))
    P = np.asarray(sp.lower_params, np.float64)
    E = int(sp.lower.warps.shape[0])
    low, high = float(rates[:E].min()), float(rates[:E].max())
    if not high - low > 1e-6:
        raise FxspaceError("turn_table: the lower examples do not turn; steering needs turns")
    grid = np.linspace(low, high, n_grid)
    h = (high - low) / 10.0
    K = np.exp(-0.5 * ((grid[:, None] - rates[None, :]) / h) ** 2)
    params = (K @ P) / np.maximum(K.sum(1, keepdims=True), 1e-300)
    return TurnTable(grid, params, low, high)


@checked
def turn_to_lower_param(table: TurnTable, turn) -> Float[Array, " d"]:
    """The lower parameter for a turning rate (°/s, clamped to the table's range);
    jittable (linear interpolation in the table)."""
    t = jnp.clip(jnp.asarray(turn), table.low, table.high)
    g = jnp.asarray(table.turn, t.dtype)
    P = jnp.asarray(table.params, t.dtype)
    return jax.vmap(lambda col: jnp.interp(t, g, col), in_axes=1)(P)


@checked
def world_positions(parents, offsets, poses: Pose) -> np.ndarray:
    """World joint positions ``(F, J, 3)`` of stacked world poses."""
    X = fk_arrays(parents, np.asarray(offsets), np.asarray(poses.root), np.asarray(poses.rotations))
    return np.asarray(X[0])


def check_turn(turn) -> float:
    """A finite turning rate (°/s)."""
    return check_scalar(turn, "turn")
