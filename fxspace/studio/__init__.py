"""Browser apps (viser): one module per paper's interactive system, plus shared helpers.

``fxspace studio RUN_DIR|CONFIG`` picks the app from the run's experiment through
the pipeline's ``APP`` (``"module:function"``; the function takes the target and
``port=``; `APPS` lists them all). viser is an optional extra
(``pip install -e ".[viewer]"``); it is imported only when an app starts.
"""

from __future__ import annotations

import contextlib
import importlib
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fxspace._progress import silent
from fxspace._validate import check_int
from fxspace.errors import FxspaceError
from fxspace.studio._edit_controller import EditorController as EditorController
from fxspace.studio._edit_controller import EditorData as EditorData
from fxspace.studio._edit_controller import load_editor_data as load_editor_data
from fxspace.studio._edit_controller import save_editor_data as save_editor_data
from fxspace.studio._editor import serve_editor as serve_editor
from fxspace.studio._ik import serve_ik as serve_ik
from fxspace.studio._ik_controller import IKController as IKController
from fxspace.studio._ik_controller import load_ik_mesh as load_ik_mesh
from fxspace.studio._motion import serve_motion as serve_motion
from fxspace.studio._motion_controller import MotionController as MotionController
from fxspace.studio._nav_controller import NavigatorController as NavigatorController
from fxspace.studio._nav_data import DENSITY_ABOVE as DENSITY_ABOVE
from fxspace.studio._nav_data import NavData as NavData
from fxspace.studio._nav_data import load_nav_data as load_nav_data
from fxspace.studio._navigator import serve_navigator as serve_navigator
from fxspace.studio._server import ServeOptions as ServeOptions
from fxspace.studio._server import density_rgba as density_rgba
from fxspace.studio._server import frame_density as frame_density
from fxspace.studio._server import read_run_config, waiting_page

__all__ = [
    "APPS",
    "OPENS_CONFIG",
    "MESH_SUFFIXES",
    "app_for",
    "opens_directly",
    "experiment_of",
    "serve",
    "serve_config",
    "EditorController",
    "EditorData",
    "load_editor_data",
    "save_editor_data",
    "serve_editor",
    "IKController",
    "load_ik_mesh",
    "serve_ik",
    "MotionController",
    "serve_motion",
    "DENSITY_ABOVE",
    "NavData",
    "NavigatorController",
    "load_nav_data",
    "serve_navigator",
    "density_rgba",
    "frame_density",
    "ServeOptions",
]

def _apps() -> dict[str, str]:
    """experiment name → ``"module:function"`` of its app: the pipelines' ``APP``
    (`fxspace.pipelines.Pipeline`), the one registry of experiments."""
    from fxspace.pipelines import available, load_pipeline

    out = {}
    for name in available():
        app = getattr(load_pipeline(name), "APP", None)
        if isinstance(app, str):
            out[name] = app
    return out


def _opens_config() -> frozenset[str]:
    from fxspace.pipelines import load_pipeline

    return frozenset(n for n in _apps() if getattr(load_pipeline(n), "APP_OPENS_CONFIG", False))


def __getattr__(name: str) -> Any:
    # APPS / OPENS_CONFIG (stable names) read off the pipeline objects when asked
    if name == "APPS":
        return _apps()
    if name == "OPENS_CONFIG":
        return _opens_config()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: files the IK studio opens as they are (a skinned mesh)
MESH_SUFFIXES: tuple[str, ...] = (".glb", ".gltf")


def opens_directly(target: str | Path) -> bool:
    """True when ``fxspace studio TARGET`` needs no run first: a run folder, a skinned
    mesh file, or a config of an experiment in `OPENS_CONFIG`."""
    p = Path(target)
    if p.is_dir() or p.suffix.lower() in MESH_SUFFIXES:
        return True
    return experiment_of(p) in _opens_config()


def experiment_of(target: str | Path) -> str:
    """The ``experiment`` of a run folder (its ``config.toml``) or a config file; a
    ``.glb`` / ``.gltf`` file is a mesh for the ``mesh_ik`` app."""
    if Path(target).suffix.lower() in MESH_SUFFIXES:
        return "mesh_ik"
    cfg, raw = read_run_config(target)
    exp = raw.get("experiment")
    if not isinstance(exp, str):
        raise FxspaceError(f"{cfg}: no 'experiment' key")
    return exp


def app_for(experiment: str) -> Callable[..., Any]:
    """The serve function registered for ``experiment`` (imported on demand)."""
    apps = _apps()
    if experiment not in apps:
        raise FxspaceError(
            f"no studio app for experiment {experiment!r}; apps: "
            + ", ".join(f"{k} ({v})" for k, v in sorted(apps.items()))
        )
    mod, _, fn = apps[experiment].partition(":")
    return getattr(importlib.import_module(mod), fn)


def check_port(port: Any) -> int:
    """``port`` as an int in 0–65535 (0: any free port), else a `FxspaceError`."""
    return check_int(port, "port (0 picks a free one)", low=0, high=65535)


def serve(target: str | Path, port: int = 8080, **kwargs: Any) -> Any:
    """``fxspace studio TARGET``: serve the app of the target's experiment."""
    check_port(port)  # before any thread starts
    return app_for(experiment_of(target))(target, port=port, **kwargs)


def serve_config(config: str | Path, port: int = 8080, out: str | Path | None = None,
                 **kwargs: Any) -> Any:  # fmt: skip
    """``fxspace studio CONFIG``: a page opens at once with the progress while the app's
    stages are built (`fxspace.pipelines.prepare_config`: only what the app shows, in
    the run's own folder; a finished run is read as it is), then the app opens on the
    same port (the page reconnects). An experiment in `OPENS_CONFIG` opens the config
    directly."""
    from fxspace.pipelines import prepare_config

    check_port(port)
    exp = experiment_of(config)
    app = app_for(exp)
    if exp in _opens_config() or Path(config).is_dir():
        return app(config, port=port, **kwargs)
    host = kwargs.get("host", "127.0.0.1")
    warm = _warm_up(app, config, kwargs)
    with waiting_page(port, host, bool(kwargs.get("environment_map", False)),
                      f"preparing {Path(config).name}") as port:  # fmt: skip
        run_dir = prepare_config(config, out)
    if warm is not None:
        warm.join()  # the app takes what it made
    return app(run_dir, port=port, **kwargs)


def _warm_up(app: Callable[..., Any], config, kwargs: dict) -> threading.Thread | None:
    """Start the app module's ``warm(config, **kwargs)`` (what the app needs besides the
    run's stages: a face rig read and compiled) in a thread, silent, while the stages
    are prepared: the machine's cores are not all busy with them. Its failure is not
    reported here: the app does the same work again and says what failed."""
    warm = getattr(importlib.import_module(app.__module__), "warm", None)
    if warm is None:
        return None

    def run() -> None:
        with contextlib.suppress(Exception), silent():
            warm(config, **kwargs)

    t = threading.Thread(target=run, name="fxspace-warm", daemon=True)
    t.start()
    return t
