"""Browser apps (viser): one module per paper's interactive system, plus shared helpers.

``fxspace studio RUN_DIR|CONFIG`` picks the app from the run's experiment through
:data:`APPS` (experiment name → ``"module:function"``; the function takes the target and
``port=``). viser is an optional extra (``pip install -e ".[viewer]"``); it is imported
only when an app starts.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fxspace.errors import FxspaceError

__all__ = ["APPS", "app_for", "experiment_of", "serve"]

#: experiment name → ``"module:function"`` serving that experiment's app
APPS: dict[str, str] = {
    "navigation": "fxspace.studio._navigator:serve",
    "reconstruction": "fxspace.studio._editor:serve",
    "parametric_synthesis": "fxspace.studio._motion:serve",
    "mesh_ik": "fxspace.studio._ik:serve_ik",
}


def experiment_of(target: str | Path) -> str:
    """The ``experiment`` of a run folder (its ``config.toml``) or a config file."""
    from fxspace.config import load_toml

    p = Path(target)
    cfg = p / "config.toml" if p.is_dir() else p
    if not cfg.is_file():
        raise FxspaceError(f"{target}: not a run folder with config.toml nor a config file")
    exp = load_toml(cfg).get("experiment")
    if not isinstance(exp, str):
        raise FxspaceError(f"{cfg}: no 'experiment' key")
    return exp


def app_for(experiment: str) -> Callable[..., Any]:
    """The serve function registered for ``experiment`` (imported on demand)."""
    if experiment not in APPS:
        raise FxspaceError(
            f"no studio app for experiment {experiment!r}; apps: "
            + ", ".join(f"{k} ({v})" for k, v in sorted(APPS.items()))
        )
    mod, _, fn = APPS[experiment].partition(":")
    return getattr(importlib.import_module(mod), fn)


def serve(target: str | Path, port: int = 8080, **kwargs: Any) -> Any:
    """``fxspace studio TARGET``: serve the app of the target's experiment."""
    return app_for(experiment_of(target))(target, port=port, **kwargs)
