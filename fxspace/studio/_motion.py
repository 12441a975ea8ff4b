"""Live controller for decoupled parametric synthesis (Ha & Han) in the browser
(``pip install -e ".[viewer]"``).

``fxspace studio RUN_DIR`` (or a ``parametric_synthesis`` config) builds the set-up's two
spaces and serves a viser page with:

- the character playing, one `fxspace.motion.synthesize_step` per frame (the clip
  loops when the lower clock reaches its end);
- sliders for the joy/sad weight (the mood walk) and for α (eqs. 2–3);
- draggable targets (transform gizmos): the foot (the lower parameter: final left-foot
  position, or the right toe at the strike) and the hand (the upper parameter, left-hand
  position at the key time, taken relative to the character's current root frame);
- the parameter-space samples drawn (paper Fig. 2): the lower samples on the ground, the
  upper samples re-placed (§3.2) around the character, moving when the foot target moves;
- record → BVH.

`MotionController` holds the state and the actions (testable without a browser);
`serve_motion` draws it and wires the page to it; `serve` builds it from a run
folder or config.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.errors import FxspaceError
from fxspace.io import write_bvh
from fxspace.rotations import quat_rotate
from fxspace.studio._server import (
    Player,
    ServeOptions,
    attach_stop,
    density_rgba,
    frame_density,
    new_server,
    run_until_interrupted,
    serialized,
)

__all__ = ["MotionController", "load_setup", "serve_motion", "serve", "START_DELAY_S"]

START_DELAY_S = 1.0
"""Seconds the first page is given to draw the scene before the walker starts walking."""


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

    def status(self) -> str:
        s = self.state.synth
        up = (
            f"joy {self.joy:.2f}"
            if not self.parametric
            else "hand " + " ".join(f"{v:+.2f}" for v in self.hand_param)
        )
        turn = f" · turn {self.turn:+.0f}°/s" if self.table is not None else ""
        return (
            f"**{self.setup.name}** · frame {self.frame} · T_L {float(s.t_lower):.1f} · "
            f"T_U {float(s.t_upper):.1f} · α {self.alpha:.2f} · {up}{turn}  \n{self.message}"
        )


def load_setup(target: str | Path, setup: str | None = None) -> M.Setup:
    """Build the set-up of a ``parametric_synthesis`` run folder (its ``config.toml``) or
    config file; ``setup`` picks one of the config's ``setups`` (default the first). A
    finished run folder's stored set-up is read, not rebuilt (see
    `fxspace.pipelines.parametric_synthesis.load_setup`)."""
    from fxspace.pipelines import parametric_synthesis as ps

    return ps.load_setup(target, setup)  # another experiment: an error naming both


def _bones(parents) -> tuple[np.ndarray, np.ndarray]:
    j = np.asarray([k for k, p in enumerate(parents) if p >= 0])
    return np.asarray(parents)[j], j


def body_mesh(X: np.ndarray, parents, radius: float = 0.045, sides: int = 10):
    """Shaded limbs: one cylinder per bone (``sides`` facets, radius ``radius``) from the
    world joint positions ``X`` ``(J, 3)``; joints get spheres separately (`_SPHERE`).
    Returns ``(vertices (V, 3) float32, faces (F, 3) uint32)``."""
    pi, ji = _bones(parents)
    a, b = X[pi], X[ji]
    d = b - a
    L = np.linalg.norm(d, axis=1)
    keep = L > 1e-4
    a, b, d, L = a[keep], b[keep], d[keep], L[keep]
    u = d / L[:, None]
    h = np.where(np.abs(u[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(u, h)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = radius * (
        np.cos(ang)[None, :, None] * e1[:, None] + np.sin(ang)[None, :, None] * e2[:, None]
    )
    V = np.concatenate([a[:, None] + ring, b[:, None] + ring], axis=1)  # (B, 2·sides, 3)
    k = np.arange(sides)
    k1 = (k + 1) % sides
    quad = np.concatenate(
        [np.stack([k, k1, sides + k], 1), np.stack([k1, sides + k1, sides + k], 1)]
    )
    F = quad[None] + (2 * sides * np.arange(len(a)))[:, None, None]
    return V.reshape(-1, 3).astype(np.float32), F.reshape(-1, 3).astype(np.uint32)


def _sphere(n_lat: int = 6, n_lon: int = 10):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    v = np.stack([np.sin(th)[:, None] * np.cos(ph), np.cos(th)[:, None] * np.ones_like(ph),
                  np.sin(th)[:, None] * np.sin(ph)], -1).reshape(-1, 3)  # fmt: skip
    f = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            f += [[a, a + n_lon, b], [b, a + n_lon, b + n_lon]]
    return v.astype(np.float32), np.asarray(f, np.uint32)


_SPHERE = _sphere()


def samples_image(P: np.ndarray, current: np.ndarray, size: int = 160) -> np.ndarray:
    """The sample cloud ``P`` ``(S, 2)`` of a parameter space as an RGBA image, the
    current parameter marked in red (the separate panel of the app)."""
    dens = frame_density(np.concatenate([P, current[None]]), size)
    img = density_rgba(dens.counts[::-1], (60, 60, 140))
    img[..., 3] = np.maximum(img[..., 3], 30)
    c = np.clip(((current - dens.lo) / (dens.hi - dens.lo) * size).astype(int), 2, size - 3)
    img[size - 1 - c[1] - 2 : size - c[1] + 2, c[0] - 2 : c[0] + 3] = (220, 40, 40, 255)
    return img


def _follow_camera(server, target: np.ndarray) -> None:
    for client in server.get_clients().values():
        cam = client.camera
        off = np.asarray(cam.position) - np.asarray(cam.look_at)
        with client.atomic():
            cam.look_at = tuple(target)
            cam.position = tuple(target + off)


def _scene(server):
    """Ground plane, grid, light; Y up."""
    server.scene.set_up_direction("+y")
    g = 30.0
    ground = server.scene.add_mesh_simple(
        "/ground/plane", np.asarray([[-g, -0.002, -g], [g, -0.002, -g], [g, -0.002, g],
                                     [-g, -0.002, g]], np.float32),
        np.asarray([[0, 2, 1], [0, 3, 2]], np.uint32), color=(205, 200, 185),
        side="double", receive_shadow=True,
    )  # fmt: skip
    grid = server.scene.add_grid("/ground/grid", width=2 * g, height=2 * g, plane="xz",
                                 cell_size=1.0)  # fmt: skip
    return ground, grid


def bone_instances(X: np.ndarray, parents, radius: float = 0.045):
    """The limbs as instances of one unit cylinder (radius 1, from z = 0 to z = 1), one per
    bone: ``(wxyzs (B, 4), positions (B, 3), scales (B, 3))`` float32, the rotation taking
    +z to the bone, the position at the parent joint, the scale ``(r, r, length)``.

    What the app sends per frame instead of a new mesh (`body_mesh`): three small arrays
    that viser updates in place, so a software-rendered page keeps up."""
    pi, ji = _bones(parents)
    a = np.asarray(X, np.float64)[pi]
    d = np.asarray(X, np.float64)[ji] - a
    L = np.linalg.norm(d, axis=1)
    u = d / np.maximum(L, 1e-12)[:, None]
    # shortest-arc quaternion from +z to u: (1 + u_z, −u_y, u_x, 0), normalised
    q = np.stack([1.0 + u[:, 2], -u[:, 1], u[:, 0], np.zeros_like(L)], axis=1)
    flip = q[:, 0] < 1e-9  # u ≈ −z (or a zero-length bone pointing nowhere): 180° about x
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.stack([np.full_like(L, radius), np.full_like(L, radius), L], axis=1)
    return q.astype(np.float32), a.astype(np.float32), scales.astype(np.float32)


def _unit_cylinder(sides: int = 10) -> tuple[np.ndarray, np.ndarray]:
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(sides)], 1)
    V = np.concatenate([ring, ring + [0.0, 0.0, 1.0]]).astype(np.float32)
    k = np.arange(sides)
    k1 = (k + 1) % sides
    F = np.concatenate([np.stack([k, k1, sides + k], 1), np.stack([k1, sides + k1, sides + k], 1)])
    return V, F.astype(np.uint32)


class _Body:
    """The character's scene nodes, made once and then updated in place (only the changed
    arrays travel to the page each frame)."""

    def __init__(self, server, ctl):
        self.server, self.ctl = server, ctl
        X = ctl.joints()
        q, p, s = bone_instances(X, ctl.skel.parents)
        cyl = _unit_cylinder()
        sc = server.scene
        self.limbs = sc.add_batched_meshes_simple(
            "/character/limbs", cyl[0], cyl[1], batched_wxyzs=q, batched_positions=p,
            batched_scales=s, batched_colors=(70, 110, 170), lod="off",
        )  # fmt: skip
        self.joints = sc.add_batched_meshes_simple(
            "/character/joints", _SPHERE[0] * 0.05, _SPHERE[1],
            batched_wxyzs=np.tile(np.float32([1, 0, 0, 0]), (len(X), 1)),
            batched_positions=X.astype(np.float32), batched_colors=(90, 130, 190), lod="off",
        )  # fmt: skip
        feet, cols = self._feet(X)
        self.contacts = sc.add_batched_meshes_simple(
            "/ground/contacts", _SPHERE[0] * np.asarray([0.09, 0.004, 0.09], np.float32),
            _SPHERE[1], batched_wxyzs=np.tile(np.float32([1, 0, 0, 0]), (len(feet), 1)),
            batched_positions=feet, batched_colors=cols, lod="off",
        )  # fmt: skip
        self.samples = None

    def _feet(self, X):
        feet = X[list(self.ctl.setup.feet)].astype(np.float32) * np.float32([1, 0, 1])
        on = [(40, 200, 60) if c else (150, 150, 150) for c in self.ctl.contacts()]
        return feet, np.asarray(on, np.uint8)

    def draw(self, show_samples: bool) -> None:
        X = self.ctl.joints()
        q, p, s = bone_instances(X, self.ctl.skel.parents)
        feet, cols = self._feet(X)
        with self.server.atomic():
            self.limbs.batched_wxyzs, self.limbs.batched_positions = q, p
            self.limbs.batched_scales = s
            self.joints.batched_positions = X.astype(np.float32)
            self.contacts.batched_positions, self.contacts.batched_colors = feet, cols
            up = self.ctl.upper_samples_world() if show_samples else None
            if up is not None and self.samples is None:
                self.samples = self.server.scene.add_point_cloud(
                    "/samples/upper", up.astype(np.float32), (60, 170, 60), point_size=0.015
                )
            elif up is not None:
                self.samples.points = up.astype(np.float32)
            if self.samples is not None:
                self.samples.visible = up is not None


def _panel(server, ctl):
    """The separate panel: the lower samples (and, parametric, the upper ones)."""
    with server.gui.add_folder("Parameter spaces (samples)"):
        P = np.asarray(ctl.sp.lower_params)[:, :2]
        low = server.gui.add_image(samples_image(P, ctl.lower_param[:2]), label="Lower")
        upp = None
        if ctl.parametric:
            U = np.asarray(ctl.state.synth.upper_params)[:, [0, 1]]
            upp = server.gui.add_image(samples_image(U, ctl.hand_param[[0, 1]]), label="Upper")

    def update() -> None:
        low.image = samples_image(P, ctl.lower_param[:2])
        if upp is not None:
            U = np.asarray(ctl.state.synth.upper_params)[:, [0, 1]]
            upp.image = samples_image(U, ctl.hand_param[[0, 1]])

    return update


def _controls(server, ctl, draw, export_path, playing: bool):
    """The GUI controls, each wired to one controller method."""
    g = server.gui
    status = g.add_markdown(ctl.status())
    play = g.add_checkbox("Playing", playing)
    follow = g.add_checkbox("Follow camera", True)
    lo, hi = ctl.turn_range()
    turn = g.add_slider(
        "Turn", min(lo, -1.0), max(hi, 1.0), 0.5, ctl.turn,
        hint="turning rate, deg/s (+ left)", disabled=ctl.table is None,
    )  # fmt: skip
    left, right = g.add_button("◀ Left"), g.add_button("Right ▶")
    joy = g.add_slider("Joy", 0.0, 1.0, 0.01, ctl.joy, disabled=ctl.parametric)
    alpha = g.add_slider("Alpha", 0.0, 1.0, 0.01, ctl.alpha)
    show = g.add_checkbox("Show samples", True)
    rec, stop = g.add_button("Record"), g.add_button("Stop and write BVH")

    def act(fn):
        def cb(_e) -> None:
            fn()
            turn.value = ctl.turn
            draw()

        return cb

    turn.on_update(lambda _e: (ctl.set_turn(turn.value), draw()))
    left.on_click(act(lambda: ctl.nudge_turn(+1)))
    right.on_click(act(lambda: ctl.nudge_turn(-1)))
    joy.on_update(lambda _e: (ctl.set_joy(joy.value), draw()))
    alpha.on_update(lambda _e: (ctl.set_alpha(alpha.value), draw()))
    rec.on_click(act(ctl.start_recording))
    stop.on_click(act(lambda: ctl.stop_recording(export_path)))
    return status, play, follow, show


def serve_motion(
    setup: M.Setup,
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    environment_map: bool = False,
    block: bool = True,
    fps: float = 30.0,
    export_path: str | Path = "recording.bvh",
    playing: bool = True,
    options: ServeOptions | None = None,
    server=None,
):
    """Serve the live controller for ``setup`` (``options`` or the old keywords; ``port=0``
    picks a free port): a shaded body walking on a ground plane (feet shaded green in
    contact), a camera that follows, steering (turn slider, ◀ / ▶), the upper control
    (joy or the hand gizmo), α, the sample clouds on their own panel, record → BVH. With
    ``block=False`` returns ``(server, controller)`` at once (stop with ``server.stop()``).
    `server`: a running viser server to draw into (`serve` opens the page first, with
    the ground and a progress line, while the set-up loads)."""
    o = options or ServeOptions(port, host, fps, block, environment_map)
    server = server if server is not None else new_server(o.port, o.host, o.environment_map)
    ctl = MotionController(setup)
    ground, grid = _scene(server)
    refresh_panel = _panel(server, ctl)
    state: dict = {}
    body = _Body(server, ctl)

    @serialized(server)
    def draw() -> None:
        body.draw(bool(state["show"].value))
        state["status"].content = ctl.status()

    state["status"], state["play"], state["follow"], state["show"] = _controls(
        server, ctl, draw, export_path, playing
    )
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

    snapped: list = [None]

    @serialized(server)
    def tick() -> None:
        # every frame: the step and the body; the rest at a lower rate (a page rendered in
        # software WebGL falls behind when every control changes 30 times a second)
        ctl.step()
        body.draw(bool(state["show"].value))
        r = ctl.root * np.asarray([1.0, 0.0, 1.0])
        snap = tuple(np.round(r / 10.0) * 10.0)
        if snap != snapped[0]:
            ground.position = grid.position = snapped[0] = snap
        if state["follow"].value and ctl.frame % 2 == 0:
            _follow_camera(server, r + np.asarray([0.0, 0.9, 0.0]))
        if ctl.frame % 6 == 0:
            state["status"].content = ctl.status()
        if ctl.frame % 15 == 0:
            refresh_panel()

    draw()
    # plays only while a page is open: the walker does not walk off before anyone looks,
    # and no frames are made that nobody receives; and only once the first page has had
    # a moment to draw the scene (a page still starting, flooded with 30 updates a second,
    # drew its first frame seconds later when rendered in software)
    seen: dict = {}

    def playing_now() -> bool:
        clients = server.get_clients()
        if not (state["play"].value and clients):
            return False
        now = time.monotonic()
        first = min(seen.setdefault(c, now) for c in clients)
        return now - first >= START_DELAY_S

    attach_stop(server, Player(tick, playing_now, o.fps))
    if o.block:
        run_until_interrupted(server, "motion controller", o.host)
    return server, ctl


def serve(target: str | Path, port: int = 8080, **kwargs):
    """``fxspace studio TARGET`` for a ``parametric_synthesis`` run folder or config: build
    the set-up (``setup=NAME`` picks one) and serve the live controller."""
    setup = kwargs.pop("setup", None)
    print(f"fxspace studio: building the parametric spaces of {target} …")
    p = Path(target)
    kwargs.setdefault("export_path", (p if p.is_dir() else Path(".")) / "recording.bvh")
    # the page first: the ground and a progress line while the set-up and the controller
    # (JAX tracing, a few seconds even with the compilation cache) are built
    given = {k: kwargs.pop(k) for k in ("host", "fps", "block", "environment_map") if k in kwargs}
    o = kwargs.pop("options", None) or ServeOptions(port, **given)
    server = new_server(o.port, o.host, o.environment_map)
    try:
        _scene(server)
        note = server.gui.add_markdown(f"**building the parametric spaces of** `{p.name}` …")
        st = load_setup(target, setup)
        note.content = "**compiling the controller** …"
        out = serve_motion(st, server=server, options=dataclasses.replace(o, block=False), **kwargs)
        note.remove()
    except BaseException:
        server.stop()
        raise
    if o.block:
        run_until_interrupted(server, "motion controller", o.host)
    return out
