"""Where the real capture data lives: one setting, ``FXSPACE_DATA``.

The data is never part of the package or the repository. ``data_root()`` returns
``$FXSPACE_DATA`` when set, else ``../shared/data`` relative to the current directory
or to the repository checkout (when that folder exists), else ``None``.
"""

from __future__ import annotations

import os
from pathlib import Path

from fxspace.errors import DataNotFoundError

__all__ = ["data_root", "data_path", "ENV_VAR"]

ENV_VAR = "FXSPACE_DATA"
_REPO = Path(__file__).resolve().parent.parent


def data_root() -> Path | None:
    """The data root, or ``None`` when no data folder can be found."""
    env = os.environ.get(ENV_VAR)
    if env:
        p = Path(env).expanduser()
        return p if p.is_dir() else None
    for cand in (Path.cwd() / ".." / "shared" / "data", _REPO / ".." / "shared" / "data"):
        if cand.is_dir():
            return cand.resolve()
    return None


def data_path(*parts: str) -> Path:
    """Path of a file under the data root; raises ``DataNotFoundError`` with the fix.

    An absolute path (a single absolute part) is kept as it is, never re-rooted."""
    if len(parts) == 1 and Path(parts[0]).expanduser().is_absolute():
        p = Path(parts[0]).expanduser()
        if not p.exists():
            raise DataNotFoundError(f"{p} does not exist")
        return p
    root = data_root()
    env = os.environ.get(ENV_VAR)
    if root is None and env:
        e = Path(env).expanduser()
        why = (
            "is a file, not a folder"
            if e.is_file()
            else "does not exist"
            if not e.exists()
            else "is not a folder"
        )
        raise DataNotFoundError(
            f"{ENV_VAR}={env} {why}; point {ENV_VAR} at the folder that holds face/, "
            "body/ and mesh/"
        )
    if root is None:
        raise DataNotFoundError(
            f"real capture data not found: set {ENV_VAR} to the folder that holds face/, "
            "body/ and mesh/ (defaults to ../shared/data when it exists)"
        )
    p = root.joinpath(*parts)
    if not p.exists():
        raise DataNotFoundError(f"{p} does not exist under the data root {root} ({ENV_VAR})")
    return p
