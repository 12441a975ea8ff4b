"""Helpers shared by the studio apps: the viser server, a dense face driven by markers,
a 2-D pad in scene coordinates, a player thread, blocking until Ctrl-C."""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fxspace._progress import listening
from fxspace.errors import FxspaceError
from fxspace.studio._faces import RIG_COLOURS, DenseFace, RigFace, studio_face

__all__ = [
    "DenseFace",
    "RigFace",
    "RIG_COLOURS",
    "studio_face",
    "waiting_page",
    "FrameDensity",
    "PadFrame",
    "Player",
    "ServeOptions",
    "density_rgba",
    "frame_density",
    "new_server",
    "ray_plane_z0",
    "read_run_config",
    "run_until_interrupted",
    "serialized",
    "status_markdown",
]


@dataclasses.dataclass(frozen=True)
class ServeOptions:
    """How an app is served, shared by every app (``serve_*(..., options=ServeOptions())``).

    **Fields:** `port` (``0`` picks a free one), `host` (``127.0.0.1``: local only),
    `fps` of the player, `block` (serve until Ctrl-C; ``False`` returns the running
    server, as tests do), `environment_map` (viser's image-based lighting, an HDR
    environment; off by default: a soft ambient + a key light instead, and no shadow maps.
    On a page rendered in software WebGL the environment map's pre-filtering alone delays
    the first frame by ~10 s, and shadow maps make a playing app's page fall behind;
    ``fxspace studio --environment-map`` turns both back on).
    """

    port: int = 8080
    host: str = "127.0.0.1"
    fps: float = 30.0
    block: bool = True
    environment_map: bool = False


def new_server(port: int, host: str = "127.0.0.1", environment_map: bool = False):
    """A viser server bound to ``host`` (``port=0``: a free port), or a clear error when the
    viewer extra is missing."""
    try:
        import viser
    except ImportError as e:
        raise FxspaceError(
            f"the studio apps need the optional viewer extra: pip install -e '.[viewer]' ({e})"
        ) from e
    server = viser.ViserServer(host=host, port=port, verbose=False)
    if not environment_map:
        server.scene.configure_environment_map(None)
        # without the image-based light, a soft ambient + a key light from the viewer
        server.scene.add_light_ambient("/lights/ambient", intensity=0.8)
        server.scene.add_light_point("/lights/key", intensity=12.0, position=(0.5, 1.5, 4.0))
        # and no shadow maps: rendered in software (no GPU), a page drawing shadows every
        # frame could not keep up with a playing app (measured: the motion app's page never
        # answered a screenshot while playing with shadows, and did at once without)
        server.scene.configure_default_lights(True, cast_shadow=False)
    server.scene.set_up_direction("+y")
    return server


class waiting_page:  # noqa: N801 - used as a context manager, like a function
    """A page that opens at once while an app's data is built: the ground, a title and
    the work's progress (every `fxspace._progress` stage line and step, and the time
    spent). On leaving, the server stops and its port is free for the app, which opens on
    it; the page reconnects to the app by itself.

    ``with waiting_page(port, host, environment_map, title) as port: …`` (the port it
    took: ``0`` picks a free one)."""

    def __init__(self, port: int, host: str, environment_map: bool, title: str):
        self.server = new_server(port, host, environment_map)
        self.title = title
        self.lines: list[str] = []
        self.t0 = time.perf_counter()
        self.server.scene.add_grid(
            "/waiting/ground", width=6.0, height=6.0, plane="xz",
            cell_color=(200, 200, 200), section_color=(150, 150, 150),
        )  # fmt: skip
        self.note = self.server.gui.add_markdown(self._text())

    def _text(self) -> str:
        dt = time.perf_counter() - self.t0
        tail = "  \n".join(self.lines[-6:])
        return f"**{self.title}** ({dt:.0f} s)  \n{tail}"

    def tell(self, msg: str) -> None:
        if self.lines and msg.split(":")[0] == self.lines[-1].split(":")[0]:
            self.lines[-1] = msg  # a progress step replaces its previous step
        else:
            self.lines.append(msg)
        self.note.content = self._text()

    def __enter__(self) -> int:
        self._listen = listening(self.tell)
        self._listen.__enter__()
        return int(self.server.get_port())

    def __exit__(self, *exc) -> None:
        self._listen.__exit__(*exc)
        self.server.stop()


class PadFrame:
    """Maps 2-D expression-space points to the pad (scene x–y plane, size ~2) and back."""

    def __init__(self, xy: np.ndarray):
        xy = np.asarray(xy, np.float64)
        self.centre = (xy.max(0) + xy.min(0)) / 2
        self.scale = 2.0 / max(float(np.ptp(xy, axis=0).max()), 1e-12)

    def to_pad(self, xy: np.ndarray) -> np.ndarray:
        p = (np.asarray(xy, np.float64) - self.centre) * self.scale
        return np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], axis=-1)

    def to_space(self, pad_xy: np.ndarray) -> np.ndarray:
        return np.asarray(pad_xy, np.float64)[..., :2] / self.scale + self.centre


class FrameDensity(NamedTuple):
    """Frames per cell of a regular grid over the 2-D embedding's bounding box.

    - `counts`: ``(bins, bins)`` int; ``counts[i, j]`` counts the frames with y in the
      i-th row (ascending y) and x in the j-th column (ascending x): an image whose row 0
      is the bottom of the pad.
    - `lo`, `hi`: ``(2,)`` the box's lower-left and upper-right corners (x, y).
    """

    counts: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def frame_density(xy: np.ndarray, bins: int = 256) -> FrameDensity:
    """The 2-D histogram of the frames ``xy`` ``(T, 2)`` on a ``bins × bins`` grid over their
    bounding box; O(T) time, O(bins²) memory (what the pad draws instead of T points)."""
    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) == 0:
        raise FxspaceError(f"xy must be a non-empty (T, 2) array, got shape {xy.shape}")
    if int(bins) < 1:
        raise FxspaceError(f"bins must be ≥ 1, got {bins}")
    lo, hi = xy.min(0), xy.max(0)
    hi = np.where(hi > lo, hi, lo + 1e-12)  # a flat axis: one cell wide
    b = int(bins)
    cell = np.clip(((xy - lo) / (hi - lo) * b).astype(np.int64), 0, b - 1)
    counts = np.bincount(cell[:, 1] * b + cell[:, 0], minlength=b * b).reshape(b, b)
    return FrameDensity(counts, lo, hi)


def density_rgba(counts: np.ndarray, rgb=(90, 90, 90)) -> np.ndarray:
    """``(H, W, 4)`` uint8 image of ``counts``: colour ``rgb``, opacity rising with
    log(1 + count) (empty cells transparent); rows in the order of ``counts``."""
    c = np.log1p(np.asarray(counts, np.float64))
    a = c / max(float(c.max()), 1e-12)
    alpha = np.where(a > 0, 0.25 + 0.75 * a, 0.0)
    img = np.empty(c.shape + (4,), np.uint8)
    img[..., :3] = np.asarray(rgb, np.uint8)
    img[..., 3] = np.round(255 * alpha).astype(np.uint8)
    return img


def ray_plane_z0(origin, direction) -> np.ndarray | None:
    """Where the ray ``origin + s·direction`` (s > 0) meets the plane z = 0 (None if never)."""
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    if abs(d[2]) < 1e-12:
        return None
    s = -o[2] / d[2]
    return None if s <= 0 else o + s * d


def read_run_config(target: str | Path, experiment: str | None = None) -> tuple[Path, dict]:
    """``(path, config)`` of a run folder (its ``config.toml``) or a config file; with
    ``experiment``, a config of another experiment is refused naming both."""
    from fxspace.config import load_toml

    p = Path(target)
    cfg = p / "config.toml" if p.is_dir() else p
    if not cfg.is_file():
        kind = f"{experiment} " if experiment else ""
        raise FxspaceError(f"{target}: not a {kind}run folder with config.toml nor a config file")
    raw = load_toml(cfg)
    if experiment is not None and raw.get("experiment") != experiment:
        raise FxspaceError(
            f"{cfg}: experiment must be {experiment!r} for this app, got {raw.get('experiment')!r}"
        )
    return cfg, raw


def status_markdown(title: str, lines: Sequence[str], message: str = "", *,
                    after_title: str = "") -> str:  # fmt: skip
    """The status panel of every app, drawn from what its controller's ``status()``
    returned: ``title`` in bold (then ``after_title``), one line per entry of ``lines``
    (empty ones dropped), then ``message`` in italics."""
    out = [f"**{title}**{after_title}", *(ln for ln in lines if ln)]
    if message:
        out.append(f"_{message}_")
    return "  \n".join(out)


def serialized(server: Any) -> Callable[[Callable], Callable]:
    """Decorator: run the function under ``server``'s one re-entrant drawing lock.

    The player thread and the GUI callbacks both replace scene nodes by name; viser raises
    when a handle is removed under another thread's update ("Cannot assign to 'visible' on
    a removed MeshHandle"), which killed the player. Wrap every redraw and the player's
    tick with ``@serialized(server)`` so two threads never draw at once."""
    lock = getattr(server, "_fxspace_draw_lock", None)
    if lock is None:
        lock = threading.RLock()
        server._fxspace_draw_lock = lock

    def wrap(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def locked(*args, **kwargs):
            with lock:
                return fn(*args, **kwargs)

        return locked

    return wrap


class Player:
    """Calls ``tick()`` every ``1/fps`` s on a daemon thread while ``active()`` is true."""

    def __init__(self, tick: Callable[[], None], active: Callable[[], bool], fps: float = 30.0):
        self._tick, self._active, self._dt = tick, active, 1.0 / fps
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._active():
                try:
                    self._tick()
                except Exception:  # the server is going down
                    if self._stop.is_set():
                        return
                    raise
            self._stop.wait(self._dt)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


def attach_stop(server: Any, *players: Player) -> None:
    """Make ``server.stop()`` also stop the players first."""
    orig = server.stop

    def stop_all() -> None:
        for p in players:
            p.stop()
        orig()

    server.stop = stop_all


def run_until_interrupted(server: Any, what: str, host: str) -> None:
    """Print the address and block until Ctrl-C, then stop the server."""
    print(f"fxspace {what} on http://{host}:{server.get_port()} (Ctrl-C to stop)")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
