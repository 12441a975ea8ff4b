"""The live controller's state and actions (Ha & Han's decoupled parametric synthesis),
independent of any UI: `MotionController` (testable without a browser) and
`load_setup`. The page (`MotionView`, `serve_motion`) is in ``_motion``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.errors import FxspaceError
from fxspace.io import write_bvh
from fxspace.rotations import quat_rotate

__all__ = ["MotionController", "load_setup"]


class MotionController:
    """State and actions of the live controller (no UI).

    **Arguments:** ``setup`` (`fxspace.motion.Setup`), ``alpha`` (eqs. 2–3), ``loop``
    (continuous locomotion: the clocks wrap and the walker walks on, `locomotion_step`;
    ``False`` stops at the end of the lower reference clip), ``smoothing_s`` (controls are
    followed by two cascaded lags of half this time, as in `run_session`).
    """

    def __init__(self, setup: M.Setup, alpha: float = 0.5, loop: bool = True,
                 smoothing_s: float = 0.3):  # fmt: skip
        self.setup = setup
        self.sp = sp = setup.spaces
        self.skel = setup.skeleton
        self.alpha = float(alpha)
        self.loop = loop
        self.smoothing_s = float(smoothing_s)
        self.parametric = sp.upper_joint >= 0
        self.joy = 0.5
        try:
            self.table = M.session_turn_table(setup)
        except FxspaceError:  # examples that do not turn: no steering
            self.table = None
        self.turn = 0.0 if self.table is None else float(np.clip(0.0, self.table.low,
                                                                 self.table.high))  # fmt: skip
        self.lower_param = (
            np.asarray(M.turn_to_lower_param(self.table, self.turn), np.float64)
            if self.table is not None else np.asarray(sp.lower_params[0], np.float64)
        )  # fmt: skip
        self.hand_param = np.asarray(sp.upper_params[0], np.float64) if self.parametric else None
        self._lag = [np.concatenate([self.lower_param, self._upper_target()])] * 2
        self.state = M.init_locomotion(sp, jnp.asarray(self.lower_param, sp.lam.dtype))
        up, low = self._params()
        # compiled ahead of time and kept on disk: a new process skips tracing the step
        self._step = M.locomotion_stepper(sp, self.state, up, low)
        self.cycle_origin = (np.zeros(3), 0.0)
        self.recording: list[tuple[np.ndarray, np.ndarray]] | None = None
        self.frame = 0
        self.message = ""
        self.rotations, self.root = self._pose_now()

    # ------------------------------------------------------------------ parameters
    def _upper_target(self) -> np.ndarray:
        if self.parametric:
            return np.asarray(self.hand_param, np.float64)
        return np.asarray([self.joy, 1.0 - self.joy])

    def upper_param(self) -> jnp.ndarray:
        return jnp.asarray(self._lag[1][self.lower_param.size :])

    def set_joy(self, w: float) -> None:
        """Joy weight in [0, 1] (sad = 1 − joy); the mood walk's upper control."""
        self.joy = float(np.clip(w, 0.0, 1.0))

    def set_alpha(self, a: float) -> None:
        self.alpha = float(np.clip(a, 0.0, 1.0))

    def turn_range(self) -> tuple[float, float]:
        """Turning rates the examples span (°/s, positive = left); ``(0, 0)`` without."""
        return (0.0, 0.0) if self.table is None else (self.table.low, self.table.high)

    def set_turn(self, deg_per_s: float) -> None:
        """Steer: the turning rate (°/s, clamped to the examples' range) → lower parameter."""
        if self.table is None:
            return
        self.turn = float(np.clip(deg_per_s, *self.turn_range()))
        self.lower_param = np.asarray(M.turn_to_lower_param(self.table, self.turn), np.float64)

    def nudge_turn(self, sign: int) -> None:
        """Arrow keys / buttons: one tenth of the range to the left (+1) or right (−1)."""
        lo, hi = self.turn_range()
        self.set_turn(self.turn + sign * 0.1 * (hi - lo))

    def _to_cycle_frame(self, world) -> np.ndarray:
        pos, yaw = self.cycle_origin
        rel = np.asarray(world, np.float64) - pos
        c, s = np.cos(-yaw), np.sin(-yaw)
        return np.asarray([c * rel[0] + s * rel[2], rel[1], -s * rel[0] + c * rel[2]])

    def _from_cycle_frame(self, p: np.ndarray) -> np.ndarray:
        pos, yaw = self.cycle_origin
        c, s = np.cos(yaw), np.sin(yaw)
        p = np.atleast_2d(p)
        out = np.stack([c * p[:, 0] + s * p[:, 2], p[:, 1], -s * p[:, 0] + c * p[:, 2]], 1)
        return out + pos

    def set_foot_target(self, world) -> None:
        """The lower parameter from a world point, in the frame where the current cycle
        started (start-aligned clips: at the start that is the world); only the parameter's
        dimensions (e.g. x, z) are taken."""
        w = self._to_cycle_frame(world)
        self.lower_param = w[np.asarray(self.sp.lower_dims)]

    def set_hand_target(self, world) -> None:
        """The upper parameter from a world point, expressed in the character's current
        root frame (ground position and heading)."""
        if not self.parametric:
            return
        X = self.joints()
        rel = np.asarray(world, np.float64) - np.asarray([X[0, 0], 0.0, X[0, 2]])
        h = M.heading_quat(jnp.asarray(self.rotations[0]))
        self.hand_param = np.asarray(quat_rotate(M.quat_conj(h), jnp.asarray(rel)))

    def foot_target_world(self) -> np.ndarray:
        out = np.zeros(3)
        out[np.asarray(self.sp.lower_dims)] = self.lower_param
        return self._from_cycle_frame(out)[0]

    def hand_target_world(self) -> np.ndarray | None:
        if not self.parametric:
            return None
        return self._from_root_frame(self.hand_param[None])[0]

    # ------------------------------------------------------------------ playing
    def _params(self):
        n = self.lower_param.size
        c = self._lag[1]
        dt = self.sp.lam.dtype
        return jnp.asarray(c[n:], dt), jnp.asarray(c[:n], dt)

    def _pose_now(self):
        up, low = self._params()
        _, pose = self._step(self.state, up, low, self.alpha, 0.0)
        return np.asarray(pose.rotations), np.asarray(pose.root)

    def step(self) -> None:
        """One animation frame: the controls followed (lags), then `locomotion_step`."""
        target = np.concatenate([self.lower_param, self._upper_target()])
        dt_s, tau = 1.0 / float(self.skel.rate), self.smoothing_s / 2
        a = M.smooth_controls(self._lag[0], target, dt_s, tau)
        self._lag = [a, M.smooth_controls(self._lag[1], a, dt_s, tau)]
        up, low = self._params()
        cycles = float(self.state.cycles)
        self.state, pose = self._step(self.state, up, low, self.alpha, 1.0)
        if float(self.state.cycles) != cycles:  # a new cycle starts here
            self.cycle_origin = (np.asarray(self.state.position, np.float64),
                                 float(self.state.yaw))  # fmt: skip
        self.rotations, self.root = np.asarray(pose.rotations), np.asarray(pose.root)
        self.frame += 1
        if self.recording is not None:
            self.recording.append((self.rotations, self.root))
        if not self.loop and float(self.state.cycles) > 0:
            self.state = M.init_locomotion(self.sp, low)

    def joints(self) -> np.ndarray:
        """World joint positions of the current pose, ``(J, 3)``."""
        X = M.fk_arrays(self.skel.parents, np.asarray(self.skel.offsets), self.root, self.rotations)
        return np.asarray(X[0])

    def contacts(self, height: float = 0.04) -> list[bool]:
        """Whether each foot (`Setup.feet`) touches the ground plane (within ``height``)."""
        X = self.joints()
        return [bool(X[j, 1] < height) for j in self.setup.feet]

    def _from_root_frame(self, p: np.ndarray) -> np.ndarray:
        X = self.joints()
        h = np.asarray(M.heading_quat(jnp.asarray(self.rotations[0])))
        w = np.asarray(quat_rotate(jnp.broadcast_to(h, (p.shape[0], 4)), jnp.asarray(p)))
        return w + np.asarray([X[0, 0], 0.0, X[0, 2]])

    def upper_samples_world(self) -> np.ndarray | None:
        """The re-placed upper samples (§3.2), drawn around the character (paper Fig. 2)."""
        if not self.parametric:
            return None
        return self._from_root_frame(np.asarray(self.state.synth.upper_params))

    def lower_samples_world(self) -> np.ndarray:
        P = np.asarray(self.sp.lower_params)
        out = np.zeros((P.shape[0], 3))
        out[:, np.asarray(self.sp.lower_dims)] = P
        return self._from_cycle_frame(out)

    # ------------------------------------------------------------------ recording
    def start_recording(self) -> None:
        self.recording = []
        self.message = "recording …"

    def stop_recording(self, path: str | Path) -> Path | None:
        """Write the recorded frames as BVH; returns the path (``None`` if nothing)."""
        rec, self.recording = self.recording, None
        if not rec:
            self.message = "nothing recorded"
            return None
        q = np.stack([r[0] for r in rec])
        r = np.stack([r[1] for r in rec])
        mot = dataclasses.replace(self.skel, root_translation=r, rotations=q)
        out = write_bvh(path, mot, scale=self.setup.scale)
        self.message = f"wrote {len(rec)} frames to {out}"
        return out

    def status(self) -> dict:
        """What the status line shows, as data (`MotionView` renders it): the ``setup``'s
        name, ``frame``, the clocks ``t_lower`` and ``t_upper``, ``alpha``, the upper
        control (``joy``, or ``hand``: the hand parameter; the other is None), ``turn``
        (°/s; None without steering), ``recording``, ``max_clock_rate`` (the bound on
        eqs. 2–3, `fxspace.motion.clock_bounds`; inf: as printed) and the last
        ``message``."""
        s = self.state.synth
        return {
            "setup": self.setup.name,
            "frame": int(self.frame),
            "t_lower": float(s.t_lower),
            "t_upper": float(s.t_upper),
            "alpha": float(self.alpha),
            "joy": None if self.parametric else float(self.joy),
            "hand": [float(v) for v in self.hand_param] if self.parametric else None,
            "turn": float(self.turn) if self.table is not None else None,
            "recording": self.recording is not None,
            "max_clock_rate": float(self.setup.spaces.max_clock_rate),
            "message": self.message,
        }


def load_setup(target: str | Path, setup: str | None = None) -> M.Setup:
    """Build the set-up of a ``parametric_synthesis`` run folder (its ``config.toml``) or
    config file; ``setup`` picks one of the config's ``setups`` (default the first). A
    finished run folder's stored set-up is read, not rebuilt (see
    `fxspace.pipelines.parametric_synthesis.load_setup`)."""
    from fxspace.pipelines import parametric_synthesis as ps

    return ps.load_setup(target, setup)  # another experiment: an error naming both
