"""Figures (matplotlib). The numerical core never imports this package; each function
returns a ``matplotlib.figure.Figure``. `import fxspace` does not load it: `fx.plot` is
imported on first access."""

import matplotlib as _mpl

if _mpl.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
    try:
        import os as _os

        if not _os.environ.get("DISPLAY"):
            _mpl.use("Agg")
    except Exception:  # pragma: no cover
        pass

from fxspace.plot._bench import plot_bench_record as plot_bench_record
from fxspace.plot._controlpoints import plot_control_points as plot_control_points
from fxspace.plot._controlpoints import plot_reconstruction_frames as plot_reconstruction_frames
from fxspace.plot._controlpoints import plot_scene_errors as plot_scene_errors
from fxspace.plot._controlpoints import plot_segmentation as plot_segmentation
from fxspace.plot._expression import plot_embedding as plot_embedding
from fxspace.plot._expression import plot_embedding_panels as plot_embedding_panels
from fxspace.plot._expression import plot_sweep as plot_sweep
from fxspace.plot._mesh import plot_ik_poses as plot_ik_poses
from fxspace.plot._mesh import plot_model_speedups as plot_model_speedups
from fxspace.plot._mesh import plot_time_per_frame as plot_time_per_frame
from fxspace.plot._mesh import plot_vs_markers as plot_vs_markers
from fxspace.plot._motion import plot_clocks as plot_clocks
from fxspace.plot._motion import plot_filmstrip as plot_filmstrip
from fxspace.plot._motion import plot_parameter_space as plot_parameter_space
from fxspace.plot._motion import plot_replacement as plot_replacement
from fxspace.plot._motion import plot_speed_vs_weight as plot_speed_vs_weight
from fxspace.plot._motion import plot_timewarp as plot_timewarp
from fxspace.plot._navigation import face_frame as face_frame
from fxspace.plot._navigation import face_wireframe as face_wireframe
from fxspace.plot._navigation import plot_level as plot_level
from fxspace.plot._navigation import plot_levels_grid as plot_levels_grid
from fxspace.plot._navigation import plot_link_radius_sweep as plot_link_radius_sweep
from fxspace.plot._navigation import write_navigation_animation as write_navigation_animation
from fxspace.plot._report import plot_report_figure as plot_report_figure
from fxspace.plot._report import plot_report_grid as plot_report_grid
from fxspace.plot._report import plot_report_metric as plot_report_metric
from fxspace.plot._synthesis import plot_arm_swing_coupling as plot_arm_swing_coupling

__all__ = [
    "plot_control_points",
    "plot_reconstruction_frames",
    "plot_scene_errors",
    "plot_segmentation",
    "plot_embedding",
    "plot_embedding_panels",
    "plot_sweep",
    "plot_ik_poses",
    "plot_model_speedups",
    "plot_time_per_frame",
    "plot_vs_markers",
    "plot_clocks",
    "plot_filmstrip",
    "plot_parameter_space",
    "plot_replacement",
    "plot_speed_vs_weight",
    "plot_timewarp",
    "face_frame",
    "face_wireframe",
    "plot_level",
    "plot_levels_grid",
    "plot_link_radius_sweep",
    "write_navigation_animation",
    "plot_report_metric",
    "plot_report_grid",
    "plot_report_figure",
    "plot_bench_record",
    "plot_arm_swing_coupling",
]
