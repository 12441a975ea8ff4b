"""Live controller for decoupled parametric synthesis (Ha & Han) in the browser
(``pip install -e ".[viewer]"``).

``fxspace studio RUN_DIR`` (or a ``parametric_synthesis`` config) builds the set-up's two
spaces and serves a viser page with:

- the character playing, one `fxspace.motion.synthesize_step` per frame (the clip
  loops when the lower clock reaches its end);
- sliders for the joy/sad weight (the mood walk) and for α (eqs. 2–3: 1 keeps the lower
  body's tempo, 0 gives it the upper body's; the status line says the bound — neither
  half runs faster than its fastest captured example at that phase);
- draggable targets (transform gizmos): the foot (the lower parameter: final left-foot
  position, or the right toe at the strike) and the hand (the upper parameter, left-hand
  position at the key time, taken relative to the character's current root frame);
- the parameter-space samples drawn (paper Fig. 2): the lower samples on the ground, the
  upper samples re-placed (§3.2) around the character, moving when the foot target moves;
- record → BVH.

`MotionController` (``_motion_controller``) holds the state and the actions
(testable without a browser); `MotionView` draws it (the ground, the body and the
samples' panel in ``_motion_scene``), `serve_motion` wires the page to it and `serve`
builds it from a run folder or config.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from fxspace import motion as M
from fxspace.studio._motion_controller import MotionController, load_setup
from fxspace.studio._motion_scene import _Body, _follow_camera, _scene, samples_image
from fxspace.studio._server import (
    Player,
    ServeOptions,
    attach_stop,
    new_server,
    run_until_interrupted,
    serialized,
    status_markdown,
)

__all__ = [
    "MotionController",
    "MotionView",
    "load_setup",
    "serve_motion",
    "serve",
    "status_text",
    "START_DELAY_S",
]

START_DELAY_S = 1.0
"""Seconds the first page is given to draw the scene before the walker starts walking."""


def alpha_help(max_clock_rate: float) -> str:
    """What α does and what bounds it (eqs. 2–3, `fxspace.motion.clock_bounds` and the
    joint-speed bound, `fxspace.motion.example_joint_steps`)."""
    base = "α: 1 keeps the lower body's tempo, 0 gives it the upper body's"
    if max_clock_rate == float("inf"):
        return base + " (eqs. 2–3 as printed: no bound, a body half may outrun every capture)"
    rate = "" if max_clock_rate == 1 else f" × {max_clock_rate:g}"
    return (base + f"; bounded: neither half runs faster than its fastest captured "
            f"example at that phase{rate}, and no joint steps farther in a frame than "
            "in any captured clip")  # fmt: skip


def status_text(st: dict) -> str:
    """The status line's Markdown from `MotionController.status` (data in, text out),
    with a help line on α and the bound on eqs. 2–3."""
    up = (f"joy {st['joy']:.2f}" if st["hand"] is None
          else "hand " + " ".join(f"{v:+.2f}" for v in st["hand"]))  # fmt: skip
    turn = f" · turn {st['turn']:+.0f}°/s" if st["turn"] is not None else ""
    bound = st.get("max_clock_rate")
    return status_markdown(
        st["setup"], [alpha_help(bound)] if bound is not None else [], st["message"],
        after_title=(f" · frame {st['frame']} · T_L {st['t_lower']:.1f} · T_U "
                     f"{st['t_upper']:.1f} · α {st['alpha']:.2f} · {up}{turn}"),
    )  # fmt: skip


class MotionView:
    """The live controller's page: the ground, the body (`_Body`), the samples' panel,
    the controls and the target gizmos, each control wired to one `MotionController`
    method (``server.fxspace_view``); `tick` plays one frame."""

    def __init__(
        self, server, ctl: MotionController, export_path, playing: bool = True, character=None
    ):
        self.server, self.ctl = server, ctl
        self.ground, self.grid = _scene(server)
        self._panel()
        self.body = _Body(server, ctl, character)
        self.redraw = serialized(server)(self._redraw)
        self._controls(export_path, playing)
        self._targets()
        self.snapped: tuple | None = None
        self.seen: dict = {}  # page → when it was first seen

    def _panel(self) -> None:
        """The separate panel: the lower samples (and, parametric, the upper ones)."""
        ctl = self.ctl
        with self.server.gui.add_folder("Parameter spaces (samples)"):
            self.P = np.asarray(ctl.sp.lower_params)[:, :2]
            self.low = self.server.gui.add_image(
                samples_image(self.P, ctl.lower_param[:2]), label="Lower"
            )
            self.upp = None
            if ctl.parametric:
                U = np.asarray(ctl.state.synth.upper_params)[:, [0, 1]]
                self.upp = self.server.gui.add_image(
                    samples_image(U, ctl.hand_param[[0, 1]]), label="Upper"
                )

    def refresh_panel(self) -> None:
        ctl = self.ctl
        self.low.image = samples_image(self.P, ctl.lower_param[:2])
        if self.upp is not None:
            U = np.asarray(ctl.state.synth.upper_params)[:, [0, 1]]
            self.upp.image = samples_image(U, ctl.hand_param[[0, 1]])

    def _controls(self, export_path, playing: bool) -> None:
        """The GUI controls, each wired to one controller method."""
        g, ctl = self.server.gui, self.ctl
        self.status = g.add_markdown(status_text(ctl.status()))
        self.play = g.add_checkbox("Playing", playing)
        self.follow = g.add_checkbox("Follow camera", True)
        lo, hi = ctl.turn_range()  # the ends rounded inwards: every value can be reached
        lo, hi = min(float(np.ceil(lo)), -1.0), max(float(np.floor(hi)), 1.0)
        self.turn = g.add_slider(
            "Turn", lo, hi, 0.5, float(np.clip(round(ctl.turn * 2) / 2, lo, hi)),
            hint="turning rate, degrees per second (+ left)", disabled=ctl.table is None,
            marks=((lo, f"{lo:.0f}°/s"), (0.0, "0"), (hi, f"{hi:+.0f}°/s")),
        )  # fmt: skip
        left, right = g.add_button("◀ Left"), g.add_button("Right ▶")
        info = getattr(ctl.setup, "info", None) or {}  # the mood clips' labels (config)
        mood = (info.get("upper_labels") or ["joy"])[0]
        joy = g.add_slider(str(mood).capitalize(), 0.0, 1.0, 0.01, ctl.joy,
                           hint=info.get("upper_axis") or f"{mood} weight",
                           disabled=ctl.parametric)  # fmt: skip
        alpha = g.add_slider("Alpha", 0.0, 1.0, 0.01, ctl.alpha)
        self.show = g.add_checkbox("Show samples", True)
        if self.body.skin is not None:
            caps = g.add_checkbox(
                "Capsule body", False, hint="the stick body instead of the character"
            )
            caps.on_update(lambda _e: (self.body.show_capsules(caps.value), self.redraw()))
            self.body.show_capsules(False)
        rec, stop = g.add_button("Record"), g.add_button("Stop and write BVH")
        self.turn.on_update(lambda _e: self._act(lambda: ctl.set_turn(self.turn.value)))
        left.on_click(lambda _e: self._act(lambda: ctl.nudge_turn(+1)))
        right.on_click(lambda _e: self._act(lambda: ctl.nudge_turn(-1)))
        joy.on_update(lambda _e: self._act(lambda: ctl.set_joy(joy.value)))
        alpha.on_update(lambda _e: self._act(lambda: ctl.set_alpha(alpha.value)))
        rec.on_click(lambda _e: self._act(ctl.start_recording))
        stop.on_click(lambda _e: self._act(lambda: self.stop_recording(export_path)))

    def stop_recording(self, export_path) -> Path | None:
        """Write the recording as BVH and, when the walker wears a character, the take
        retargeted onto it as glTF beside it (``….glb``: mesh + skin animation) and as a
        BVH of the character's skeleton (``…_character.bvh``)."""
        rec = list(self.ctl.recording or [])
        out = self.ctl.stop_recording(export_path)
        if out is not None and self.body.character is not None:
            glb = export_character_gltf(self.ctl.skel, rec, self.body.character, out)
            self.ctl.message += f"; the character in {glb.name} and {glb.stem}_character.bvh"
        return out

    def _act(self, action) -> None:
        """Run a controller action, show the turn it left, redraw."""
        action()
        if self.turn.value != self.ctl.turn:
            self.turn.value = self.ctl.turn
        self.redraw()

    def _targets(self) -> None:
        """The draggable foot (lower parameter) and hand (upper parameter) targets."""
        ctl, scene = self.ctl, self.server.scene
        foot = scene.add_transform_controls(
            "/targets/foot", scale=0.25, position=tuple(ctl.foot_target_world()),
            disable_rotations=True,
        )  # fmt: skip
        foot.on_update(lambda _e: ctl.set_foot_target(np.asarray(foot.position)))
        if ctl.parametric:
            hand = scene.add_transform_controls(
                "/targets/hand", scale=0.2, position=tuple(ctl.hand_target_world()),
                disable_rotations=True,
            )  # fmt: skip
            hand.on_update(lambda _e: ctl.set_hand_target(np.asarray(hand.position)))

    def _redraw(self) -> None:
        self.body.draw(bool(self.show.value))
        self.status.content = status_text(self.ctl.status())

    def tick(self) -> None:
        """One played frame: the step and the body every frame; the rest at a lower rate
        (a page rendered in software WebGL falls behind when every control changes 30
        times a second)."""
        ctl = self.ctl
        ctl.step()
        self.body.draw(bool(self.show.value))
        r = ctl.root * np.asarray([1.0, 0.0, 1.0])
        if self.body.skin is not None and self.body.skin.visible:  # follow the character
            r = self.body.center * np.asarray([1.0, 0.0, 1.0])
        snap = tuple(np.round(r / 10.0) * 10.0)
        if snap != self.snapped:
            self.ground.position = self.grid.position = self.snapped = snap
        if self.follow.value and ctl.frame % 2 == 0:
            _follow_camera(self.server, r + np.asarray([0.0, 0.9, 0.0]))
        if ctl.frame % 6 == 0:
            self.status.content = status_text(ctl.status())
        if ctl.frame % 15 == 0:
            self.refresh_panel()

    def playing_now(self) -> bool:
        """Plays only while a page is open (the walker does not walk off before anyone
        looks, and no frames are made that nobody receives), and only once the first
        page has had `START_DELAY_S` to draw the scene (a page still starting, flooded
        with 30 updates a second, drew its first frame seconds later in software)."""
        clients = self.server.get_clients()
        if not (self.play.value and clients):
            return False
        now = time.monotonic()
        first = min(self.seen.setdefault(c, now) for c in clients)
        return now - first >= START_DELAY_S


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
    character: str | Path | None = "auto",
):
    """Serve the live controller for ``setup`` (``options`` or the old keywords; ``port=0``
    picks a free port): a shaded body walking on a ground plane (feet shaded green in
    contact), a camera that follows, steering (turn slider, ◀ / ▶), the upper control
    (joy or the hand gizmo), α, the sample clouds on their own panel, record → BVH. With
    ``block=False`` returns ``(server, controller)`` at once (stop with ``server.stop()``).
    `server`: a running viser server to draw into (`serve` opens the page first, with
    the ground and a progress line, while the set-up loads). `character`: a skinned glTF
    the walker wears (retargeted live through the mesh IK, `fxspace.mesh.live_retarget`;
    "auto": CesiumMan from the data root when the skeleton's joints resolve; ``None``:
    the capsule body only); a "Capsule body" checkbox switches back."""
    o = options or ServeOptions(port, host, fps, block, environment_map)
    server = server if server is not None else new_server(o.port, o.host, o.environment_map)
    ctl = MotionController(setup)
    view = MotionView(server, ctl, export_path, playing, _character(setup.skeleton, character))
    server.fxspace_view = view
    view.redraw()
    attach_stop(server, Player(serialized(server)(view.tick), view.playing_now, o.fps))
    if o.block:
        run_until_interrupted(server, "motion controller", o.host)
    return server, ctl


def export_character_gltf(skel, recording, character, bvh_path) -> Path:
    """The recorded frames (``(rotations, root)`` pairs of ``skel``) retargeted onto the
    walker's character by `fxspace.mesh.retarget` (feet planted where the session's are)
    and written by `fxspace.io.write_gltf_animation` beside ``bvh_path`` (``.glb``), and
    by `fxspace.io.write_character_bvh` as a BVH of the character's own skeleton
    (``…_character.bvh``)."""
    from fxspace import io as fio
    from fxspace import mesh as fmesh

    q = np.stack([r[0] for r in recording])
    root = np.stack([r[1] for r in recording])
    take = dataclasses.replace(skel, root_translation=root, rotations=q)
    res = fmesh.retarget(take, character.mesh, list(character.pairs), baseline=False)
    glb = fio.write_gltf_animation(Path(bvh_path).with_suffix(".glb"), character.mesh, res)
    fio.write_character_bvh(glb.with_name(glb.stem + "_character.bvh"), character.mesh, res)
    return glb


def _character(skel, character):
    """The `fxspace.mesh.LiveRetarget` of ``skel`` onto ``character`` (a glTF path or
    ``"auto"``: CesiumMan), or ``None`` with the reason on the console."""
    if character is None:
        return None
    from fxspace import io as fio
    from fxspace import mesh as fmesh
    from fxspace.data import data_path
    from fxspace.errors import FxspaceError

    try:
        src = M.joint_map_for(skel, required=())
        if len(src.roles) < 6:
            raise FxspaceError(f"the skeleton's joints resolve {len(src.roles)} roles")
        path = data_path("mesh", "CesiumMan.glb") if character == "auto" else Path(character)
        man = fio.read_gltf(path)
        pairs = src.correspondences(M.joint_map_for(man.joint_names, required=()))
        lr = fmesh.live_retarget(skel, man, pairs)
    except (FxspaceError, OSError) as e:
        print(f"fxspace studio: the capsule body ({e})")
        return None
    print(f"fxspace studio: the walker wears {path.name} ({len(pairs)} joints paired, "
          f"scale {lr.scale:.2f})")  # fmt: skip
    return lr


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
