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

from ._controlpoints import plot_control_points as plot_control_points
from ._controlpoints import plot_reconstruction_frames as plot_reconstruction_frames
from ._controlpoints import plot_segmentation as plot_segmentation
from ._expression import plot_embedding as plot_embedding
from ._expression import plot_embedding_panels as plot_embedding_panels
from ._expression import plot_sweep as plot_sweep
from ._mesh import plot_ik_poses as plot_ik_poses
from ._mesh import plot_time_per_frame as plot_time_per_frame
from ._mesh import plot_vs_markers as plot_vs_markers
from ._motion import plot_clocks as plot_clocks
from ._motion import plot_filmstrip as plot_filmstrip
from ._motion import plot_parameter_space as plot_parameter_space
from ._navigation import face_frame as face_frame
from ._navigation import face_wireframe as face_wireframe
from ._navigation import plot_level as plot_level
from ._navigation import plot_levels_grid as plot_levels_grid
from ._navigation import write_navigation_animation as write_navigation_animation
