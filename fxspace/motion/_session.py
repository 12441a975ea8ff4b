"""A controller session without a browser: named controls of a set-up, a schedule of
control changes, smoothed and played by `locomotion` (continuous, steerable).

The controls of a set-up (`session_controls`):

- ``alpha`` ``[0, 1]``: eqs. (2)–(3);
- ``turn`` (walk set-ups): turning rate in degrees per second (positive = left), the range
  spanned by the walk-turn-left/right and straight example clips (`turn_table`);
- ``joy`` ``[0, 1]`` (mood walk): the joy weight of the upper body (sad = 1 − joy);
- ``hand_x``/``hand_y``/``hand_z`` (parametric upper body): the upper parameter in the
  root frame, the 5–95 % range of the upper samples;
- ``foot_x``/``foot_y``/``foot_z`` (a lower body without turning, e.g. the kicks): the
  lower parameter, the 5–95 % range of the lower samples.

Control changes are followed by two cascaded first-order lags of ``smoothing_s / 2``
seconds (a user's slider is a step; the blend weights, and so the limbs, then change
smoothly).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._validate import as_float_array, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.motion._locomotion import (
    TurnTable,
    init_locomotion,
    locomotion,
    turn_table,
    turn_to_lower_param,
    world_positions,
)
from fxspace.motion._session_checks import check_session_args

__all__ = [
    "session_controls",
    "control_defaults",
    "controls_to_params",
    "smooth_controls",
    "run_session",
    "session_turn_table",
]

_AXES = ("x", "y", "z")


def _walks(setup) -> bool:
    return setup.name in ("mood_walk", "block_walk")


def _check_setup(setup) -> None:
    if not all(hasattr(setup, a) for a in ("name", "spaces", "skeleton")):
        raise FxspaceError(
            f"setup must be a prepared set-up (fxspace.motion.prepare_setup), "
            f"got {type(setup).__name__}"
        )


def _check_controls(controls) -> None:
    if not isinstance(controls, dict) or not all(
        isinstance(v, tuple | list) and len(v) == 2 for v in controls.values()
    ):
        raise FxspaceError(
            "controls must map each control's name to its (low, high) range "
            "(fxspace.motion.session_controls)"
        )


def session_turn_table(setup) -> TurnTable | None:
    """The set-up's turning table (walks), ``None`` otherwise."""
    _check_setup(setup)
    return turn_table(setup.spaces, float(setup.skeleton.rate)) if _walks(setup) else None


def _pct(P: np.ndarray, j: int) -> tuple[float, float]:
    return float(np.percentile(P[:, j], 5)), float(np.percentile(P[:, j], 95))


def session_controls(setup, table: TurnTable | None = None) -> dict[str, tuple[float, float]]:
    """The controllable parameters of a set-up, ``{name: (low, high)}`` (see the module)."""
    _check_setup(setup)
    if table is not None and not isinstance(table, TurnTable):
        raise FxspaceError(f"table must be a TurnTable or None, got {type(table).__name__}")
    sp = setup.spaces
    out: dict[str, tuple[float, float]] = {"alpha": (0.0, 1.0)}
    if _walks(setup):
        table = table or session_turn_table(setup)
        out["turn"] = (table.low, table.high)
    else:
        P = np.asarray(sp.lower_params, np.float64)
        for j, d in enumerate(sp.lower_dims):
            out[f"foot_{_AXES[d]}"] = _pct(P, j)
    if sp.upper_joint >= 0:
        U = np.asarray(sp.upper_params, np.float64)
        for j in range(3):
            out[f"hand_{_AXES[j]}"] = _pct(U, j)
    else:
        out["joy"] = (0.0, 1.0)
    return out


@checked
def control_defaults(setup, controls: dict) -> dict[str, float]:
    """Start values: α ½, no turning, joy ½, the hand/foot at the middle of their range."""
    _check_setup(setup)
    _check_controls(controls)
    d = {k: 0.5 * (lo + hi) for k, (lo, hi) in controls.items()}
    d["alpha"] = 0.5
    if "turn" in d:
        d["turn"] = float(np.clip(0.0, *controls["turn"]))
    return d


@checked
def smooth_controls(current: np.ndarray, target: np.ndarray, dt_s: float, tau_s: float):
    """One step of a first-order lag: ``c ← c + (target − c)(1 − e^{−dt/τ})``."""
    current = as_float_array(current, "current", min_frames=0, xp="numpy").astype(np.float64)
    target = as_float_array(target, "target", min_frames=0, xp="numpy").astype(np.float64)
    if current.shape != target.shape:
        raise FxspaceError(
            f"current and target must have the same shape, got {current.shape} and {target.shape}"
        )
    dt_s = check_scalar(dt_s, "dt_s", low=0.0)
    tau_s = check_scalar(tau_s, "tau_s", low=0.0)
    if tau_s <= 0:
        return np.asarray(target, np.float64)
    return current + (target - current) * (1.0 - np.exp(-dt_s / tau_s))


@checked
def controls_to_params(setup, names: list[str], values: np.ndarray, table: TurnTable | None):
    """``(F, n)`` control values (columns ``names``) → ``(upper (F, p), lower (F, d),
    alpha (F,))`` parameter arrays for `locomotion`."""
    _check_setup(setup)
    values = as_float_array(values, "values", xp="numpy")
    if isinstance(names, str) or values.ndim != 2 or len(names) != values.shape[1]:
        raise FxspaceError(
            f"values must be (F, n) with one column per name in names, got shape "
            f"{values.shape} for {len(names) if not isinstance(names, str) else 'a string'} names"
        )
    sp = setup.spaces
    col = {n: values[:, i] for i, n in enumerate(names)}
    F = values.shape[0]
    if sp.upper_joint >= 0:
        up = np.stack([col[f"hand_{a}"] for a in _AXES], 1)
    else:
        up = np.stack([col["joy"], 1.0 - col["joy"]], 1)
    if table is not None:
        low = np.asarray(jax.vmap(lambda t: turn_to_lower_param(table, t))(col["turn"]))
    else:
        low = np.stack([col[f"foot_{_AXES[d]}"] for d in sp.lower_dims], 1)
    return up.reshape(F, -1), low.reshape(F, -1), col["alpha"]


def _targets(schedule, seconds: float, fps: float, controls: dict, start: dict) -> np.ndarray:
    names = list(controls)
    F = int(round(seconds * fps))
    T = np.tile(np.asarray([start[n] for n in names], np.float64), (F, 1))
    for item in sorted(schedule, key=lambda e: float(e[0])):
        t, change = item
        t = check_scalar(t, "schedule time", low=0.0)
        f0 = int(round(t * fps))
        for k, v in dict(change).items():
            if k not in controls:
                raise FxspaceError(
                    f"schedule: unknown parameter {k!r}; this set-up has {sorted(controls)}"
                )
            v = check_scalar(v, f"schedule value of {k}")
            T[f0:, names.index(k)] = np.clip(v, *controls[k])
    return T


def run_session(
    setup, schedule, seconds: float, smoothing_s: float = 0.3, table: TurnTable | None = None
):
    """Play a set-up for ``seconds`` at its skeleton's frame rate with the controls of
    ``schedule`` (a list of ``(time_s, {name: value})``; values clamped to the ranges of
    `session_controls`, held until changed, followed by two cascaded lags of
    ``smoothing_s / 2`` each).

    **Returns:** ``(positions, fps, names, poses)``: world joint positions ``(F, J, 3)``
    (metres, y up), the frame rate, the joint names, and the world `Pose` stack."""
    _check_setup(setup)
    seconds = check_scalar(seconds, "seconds", low=0.0, low_open=True)
    smoothing_s = check_scalar(smoothing_s, "smoothing_s", low=0.0)
    sp, skel = setup.spaces, setup.skeleton
    fps = float(skel.rate)
    schedule = check_session_args(schedule, seconds, fps, len(skel.parents))
    if table is None and _walks(setup):
        table = session_turn_table(setup)
    controls = session_controls(setup, table)
    names = list(controls)
    T = _targets(schedule, seconds, fps, controls, control_defaults(setup, controls))
    V = np.empty_like(T)
    c1 = c2 = T[0]
    for f in range(T.shape[0]):  # two cascaded lags: changes start and end smoothly
        c1 = smooth_controls(c1, T[f], 1.0 / fps, smoothing_s / 2)
        c2 = smooth_controls(c2, c1, 1.0 / fps, smoothing_s / 2)
        V[f] = c2
    up, low, alpha = controls_to_params(setup, names, V, table)
    dtype = sp.lam.dtype
    state = init_locomotion(sp, jnp.asarray(low[0], dtype))
    _, poses = locomotion(
        sp, state, jnp.asarray(up, dtype), jnp.asarray(low, dtype), jnp.asarray(alpha, dtype)
    )
    X = world_positions(skel.parents, skel.offsets, poses)
    return X, fps, list(skel.names), poses
