"""Control-point editing (Hirose & Higuchi): fused-lasso segmentation, kernel k-means
control points, in-betweens from the first/last frames + control points, fitting, RBF transfer.
"""

from fxspace.controlpoints._fitting import FitResult as FitResult
from fxspace.controlpoints._fitting import refine_control_points as refine_control_points
from fxspace.controlpoints._fused_lasso import FusedLassoResult as FusedLassoResult
from fxspace.controlpoints._fused_lasso import flsa_objective as flsa_objective
from fxspace.controlpoints._fused_lasso import fused_lasso as fused_lasso
from fxspace.controlpoints._fused_lasso import fused_lasso_solve as fused_lasso_solve
from fxspace.controlpoints._fused_lasso import tv_denoise as tv_denoise
from fxspace.controlpoints._model import ControlPointModel as ControlPointModel
from fxspace.controlpoints._model import blend_weights as blend_weights
from fxspace.controlpoints._model import compression_ratio as compression_ratio
from fxspace.controlpoints._model import control_point_model as control_point_model
from fxspace.controlpoints._model import edit_control_point as edit_control_point
from fxspace.controlpoints._model import fit_control_points as fit_control_points
from fxspace.controlpoints._model import linear_interpolation as linear_interpolation
from fxspace.controlpoints._model import reconstruct as reconstruct
from fxspace.controlpoints._model import reconstruction_error as reconstruction_error
from fxspace.controlpoints._model import residual_trajectories as residual_trajectories
from fxspace.controlpoints._model import storage_size as storage_size
from fxspace.controlpoints._model import temporal_window as temporal_window
from fxspace.controlpoints._rbf import FaceSurface as FaceSurface
from fxspace.controlpoints._rbf import face_surface as face_surface
from fxspace.controlpoints._rbf import rbf_deform as rbf_deform
from fxspace.controlpoints._rbf import rbf_transfer_matrix as rbf_transfer_matrix
from fxspace.controlpoints._segment import Segmentation as Segmentation
from fxspace.controlpoints._segment import motion_summary as motion_summary
from fxspace.controlpoints._segment import segment_motion as segment_motion
from fxspace.controlpoints._segment import segments_from_boundaries as segments_from_boundaries

__all__ = [
    "ControlPointModel",
    "blend_weights",
    "compression_ratio",
    "control_point_model",
    "edit_control_point",
    "fit_control_points",
    "linear_interpolation",
    "reconstruct",
    "reconstruction_error",
    "residual_trajectories",
    "storage_size",
    "temporal_window",
    "FitResult",
    "refine_control_points",
    "FusedLassoResult",
    "flsa_objective",
    "fused_lasso",
    "fused_lasso_solve",
    "tv_denoise",
    "FaceSurface",
    "face_surface",
    "rbf_deform",
    "rbf_transfer_matrix",
    "Segmentation",
    "motion_summary",
    "segment_motion",
    "segments_from_boundaries",
]
