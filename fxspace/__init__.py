"""fxspace: a JAX research framework for motion-capture-driven facial and character animation.

Public API (stable names, see DESIGN.md) is re-exported here explicitly.
"""

from importlib import metadata as _metadata

from . import config as config
from . import data as data
from . import errors as errors
from . import io as io
from . import plot as plot
from . import runs as runs
from .errors import CorruptFileError as CorruptFileError
from .errors import DisconnectedGraphError as DisconnectedGraphError
from .errors import FxspaceError as FxspaceError

# --- expression space (issue 2) ---
# --- end expression space ---

# --- hierarchy / navigation (issue 3) ---
# --- end hierarchy / navigation ---

# --- control points (issue 4) ---
# --- end control points ---

# --- motion (issue 5) ---
# --- end motion ---

# --- mesh IK (issue 6) ---
# --- end mesh IK ---

try:
    __version__ = _metadata.version("fxspace")
except _metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    __version__ = "0.0.0"
