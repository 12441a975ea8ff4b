"""Live controller for decoupled parametric synthesis (Ha & Han) in the browser
(``pip install -e ".[viewer]"``).

``fxspace studio RUN_DIR`` (or a ``parametric_synthesis`` config) builds the set-up's two
spaces and serves a viser page with:

- the character playing, one :func:`fxspace.motion.synthesize_step` per frame (the clip
  loops when the lower clock reaches its end);
- sliders for the joy/sad weight (the mood walk) and for α (eqs. 2–3);
- draggable targets (transform gizmos): the foot (the lower parameter: final left-foot
  position, or the right toe at the strike) and the hand (the upper parameter, left-hand
  position at the key time, taken relative to the character's current root frame);
- the parameter-space samples drawn (paper Fig. 2): the lower samples on the ground, the
  upper samples re-placed (§3.2) around the character, moving when the foot target moves;
- record → BVH.

:class:`MotionController` holds the state and the actions (testable without a browser);
:func:`serve_motion` draws it and wires the page to it; :func:`serve` builds it from a run
folder or config.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.config import config_from_dict
from fxspace.data import data_path
from fxspace.io import read_amc, read_bvh, write_bvh
from fxspace.rotations import quat_rotate
from fxspace.studio._server import (
    Player,
    attach_stop,
    new_server,
    read_run_config,
    run_until_interrupted,
    serialized,
)

__all__ = ["MotionController", "load_setup", "serve_motion", "serve"]


class MotionController:
    """State and actions of the live controller (no UI).

    **Arguments:** ``setup`` (:class:`fxspace.motion.Setup`), ``alpha`` (eqs. 2–3),
    ``loop`` (restart the clocks at the end of the lower reference clip).
    """

    def __init__(self, setup: M.Setup, alpha: float = 0.5, loop: bool = True):
        self.setup = setup
        self.sp = sp = setup.spaces
        self.skel = setup.skeleton
        self.alpha = float(alpha)
        self.loop = loop
        self.parametric = sp.upper_joint >= 0
        self.joy = 0.5
        self.lower_param = np.asarray(sp.lower_params[0], np.float64)
        self.state = M.init_state(sp, jnp.asarray(self.lower_param))
        self.hand_param = np.asarray(sp.upper_params[0], np.float64) if self.parametric else None
        self.recording: list[tuple[np.ndarray, np.ndarray]] | None = None
        self.frame = 0
        self.message = ""
        self.rotations, self.root = self._pose_now()

    # ------------------------------------------------------------------ parameters
    def upper_param(self) -> jnp.ndarray:
        if self.parametric:
            return jnp.asarray(self.hand_param)
        return jnp.asarray([self.joy, 1.0 - self.joy])

    def set_joy(self, w: float) -> None:
        """Joy weight in [0, 1] (sad = 1 − joy); the mood walk's upper control."""
        self.joy = float(np.clip(w, 0.0, 1.0))

    def set_alpha(self, a: float) -> None:
        self.alpha = float(np.clip(a, 0.0, 1.0))

    def set_foot_target(self, world) -> None:
        """The lower parameter from a world point (start-aligned clips: world = parameter
        frame); only the parameter's dimensions (e.g. x, z) are taken."""
        w = np.asarray(world, np.float64)
        self.lower_param = w[np.asarray(self.sp.lower_dims)]

    def set_hand_target(self, world) -> None:
        """The upper parameter from a world point, expressed in the character's current
        root frame (ground position and heading)."""
        if not self.parametric:
            return
        q0 = jnp.asarray(self.rotations[0])
        X = self.joints()
        rel = np.asarray(world, np.float64) - np.asarray([X[0, 0], 0.0, X[0, 2]])
        h = M.heading_quat(q0)
        self.hand_param = np.asarray(quat_rotate(M.quat_conj(h), jnp.asarray(rel)))

    def foot_target_world(self) -> np.ndarray:
        out = np.zeros(3)
        out[np.asarray(self.sp.lower_dims)] = self.lower_param
        return out

    def hand_target_world(self) -> np.ndarray | None:
        if not self.parametric:
            return None
        return self._from_root_frame(self.hand_param[None])[0]

    # ------------------------------------------------------------------ playing
    def _pose_now(self):
        _, pose = M.synthesize_step(
            self.sp, self.state, self.upper_param(), jnp.asarray(self.lower_param), self.alpha, 0.0
        )
        return np.asarray(pose.rotations), np.asarray(pose.root)

    def step(self) -> None:
        """One animation frame: the synthesis step with the current controls."""
        self.state, pose = M.synthesize_step(
            self.sp, self.state, self.upper_param(), jnp.asarray(self.lower_param), self.alpha, 1.0
        )
        self.rotations, self.root = np.asarray(pose.rotations), np.asarray(pose.root)
        self.frame += 1
        if self.recording is not None:
            self.recording.append((self.rotations, self.root))
        if self.loop and float(self.state.t_lower) >= self.sp.lam.shape[0] - 1 - 1e-6:
            self.state = M.init_state(self.sp, jnp.asarray(self.lower_param))

    def joints(self) -> np.ndarray:
        """World joint positions of the current pose, ``(J, 3)``."""
        X = M.fk_arrays(self.skel.parents, np.asarray(self.skel.offsets), self.root, self.rotations)
        return np.asarray(X[0])

    def _from_root_frame(self, p: np.ndarray) -> np.ndarray:
        X = self.joints()
        h = np.asarray(M.heading_quat(jnp.asarray(self.rotations[0])))
        w = np.asarray(quat_rotate(jnp.broadcast_to(h, (p.shape[0], 4)), jnp.asarray(p)))
        return w + np.asarray([X[0, 0], 0.0, X[0, 2]])

    def upper_samples_world(self) -> np.ndarray | None:
        """The re-placed upper samples (§3.2), drawn around the character (paper Fig. 2)."""
        if not self.parametric:
            return None
        return self._from_root_frame(np.asarray(self.state.upper_params))

    def lower_samples_world(self) -> np.ndarray:
        P = np.asarray(self.sp.lower_params)
        out = np.zeros((P.shape[0], 3))
        out[:, np.asarray(self.sp.lower_dims)] = P
        return out

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

    def status(self) -> str:
        s = self.state
        up = (
            f"joy {self.joy:.2f}"
            if not self.parametric
            else "hand " + " ".join(f"{v:+.2f}" for v in self.hand_param)
        )
        return (
            f"**{self.setup.name}** · frame {self.frame} · T_L {float(s.t_lower):.1f} · "
            f"T_U {float(s.t_upper):.1f} · α {self.alpha:.2f} · {up}  \n{self.message}"
        )


def _load_take(take: str, stride: int):
    if take.startswith("dataset-"):
        return M.drop_root(read_bvh(data_path("body", "bandai", f"{take}.bvh.gz"), scale=0.01))
    subj = take.split("_")[0]
    m = read_amc(
        data_path("body", "cmu", subj, f"{subj}.asf"),
        data_path("body", "cmu", subj, f"{take}.amc.gz"),
    )
    return m.frames(slice(None, None, stride))


def load_setup(target: str | Path, setup: str | None = None) -> M.Setup:
    """Build the set-up of a ``parametric_synthesis`` run folder (its ``config.toml``) or
    config file; ``setup`` picks one of the config's ``setups`` (default the first)."""
    _, raw = read_run_config(target, "parametric_synthesis")
    names = list(raw.get("setups", ["mood_walk"]))
    name = setup or names[0]
    data = config_from_dict(M.SetupData, dict(raw.get("data", {})))
    space = config_from_dict(M.SetupSpace, dict(raw.get("space", {})))
    stride = int(raw.get("stride", 4))
    key = jax.random.fold_in(jax.random.PRNGKey(int(raw.get("seed", 0))), names.index(name))
    return M.prepare_setup(name, lambda t: _load_take(t, stride), data, space, key)


def _bones(parents) -> tuple[np.ndarray, np.ndarray]:
    j = np.asarray([k for k, p in enumerate(parents) if p >= 0])
    return np.asarray(parents)[j], j


def serve_motion(
    setup: M.Setup,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = True,
    block: bool = True,
    fps: float = 30.0,
    export_path: str | Path = "recording.bvh",
    playing: bool = True,
):
    """Serve the live controller for ``setup``; ``port=0`` picks a free port. With
    ``block=False`` returns ``(server, controller)`` at once (stop with ``server.stop()``)."""
    server = new_server(port, host, environment_map)
    ctl = MotionController(setup)
    pi, ji = _bones(ctl.skel.parents)
    server.scene.add_grid("/ground", width=8.0, height=8.0, plane="xz")
    gui_status = server.gui.add_markdown(ctl.status())
    play = server.gui.add_checkbox("Playing", playing)
    joy = server.gui.add_slider("Joy", 0.0, 1.0, 0.01, ctl.joy, disabled=ctl.parametric)
    alpha = server.gui.add_slider("Alpha", 0.0, 1.0, 0.01, ctl.alpha)
    show = server.gui.add_checkbox("Show samples", True)
    rec = server.gui.add_button("Record")
    stop = server.gui.add_button("Stop and write BVH")

    @serialized(server)
    def draw() -> None:
        X = ctl.joints()
        seg = np.stack([X[pi], X[ji]], 1).astype(np.float32)
        server.scene.add_line_segments("/character", seg, (30, 30, 30), thickness=0.02)
        if show.value:
            low = ctl.lower_samples_world().astype(np.float32)
            server.scene.add_point_cloud("/samples/lower", low, (120, 120, 220), point_size=0.02)
            up = ctl.upper_samples_world()
            if up is not None:
                server.scene.add_point_cloud(
                    "/samples/upper", up.astype(np.float32), (60, 170, 60), point_size=0.015
                )
        gui_status.content = ctl.status()

    foot = server.scene.add_transform_controls(
        "/targets/foot", scale=0.25, position=tuple(ctl.foot_target_world()), disable_rotations=True
    )
    foot.on_update(lambda _e: ctl.set_foot_target(np.asarray(foot.position)))
    if ctl.parametric:
        hand = server.scene.add_transform_controls(
            "/targets/hand", scale=0.2, position=tuple(ctl.hand_target_world()),
            disable_rotations=True,
        )  # fmt: skip
        hand.on_update(lambda _e: ctl.set_hand_target(np.asarray(hand.position)))

    @joy.on_update
    def _(_e) -> None:
        ctl.set_joy(joy.value)
        draw()

    @alpha.on_update
    def _(_e) -> None:
        ctl.set_alpha(alpha.value)
        draw()

    @rec.on_click
    def _(_e) -> None:
        ctl.start_recording()
        draw()

    @stop.on_click
    def _(_e) -> None:
        ctl.stop_recording(export_path)
        draw()

    @serialized(server)
    def tick() -> None:
        ctl.step()
        draw()

    draw()
    attach_stop(server, Player(tick, lambda: bool(play.value), fps))
    if block:
        run_until_interrupted(server, "motion controller", host)
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a ``parametric_synthesis`` run folder or config: build
    the set-up (``setup=NAME`` picks one) and serve the live controller."""
    setup = kwargs.pop("setup", None)
    print(f"fxspace studio: building the parametric spaces of {target} …")
    p = Path(target)
    kwargs.setdefault("export_path", (p if p.is_dir() else Path(".")) / "recording.bvh")
    return serve_motion(load_setup(target, setup), port=port, **kwargs)
