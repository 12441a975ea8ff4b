"""Figures (matplotlib). The numerical core never imports this package; each function
returns a ``matplotlib.figure.Figure``."""

import matplotlib as _mpl

if _mpl.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
    try:
        import os as _os

        if not _os.environ.get("DISPLAY"):
            _mpl.use("Agg")
    except Exception:  # pragma: no cover
        pass

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
