"""Control-point editing (Hirose & Higuchi): fused-lasso segmentation, kernel k-means
control points, in-betweens from the first/last frames + control points, fitting, RBF transfer.
"""

from fxspace.controlpoints._character import Character as Character
from fxspace.controlpoints._character import character as character
from fxspace.controlpoints._character import drive_character as drive_character
from fxspace.controlpoints._character import standin_character as standin_character
from fxspace.controlpoints._edits import EditKey as EditKey
from fxspace.controlpoints._edits import FaceKey as FaceKey
from fxspace.controlpoints._edits import anchor_offsets as anchor_offsets
from fxspace.controlpoints._edits import anchor_vertex as anchor_vertex
from fxspace.controlpoints._edits import apply_edits as apply_edits
from fxspace.controlpoints._edits import check_face_keys as check_face_keys
from fxspace.controlpoints._edits import control_positions as control_positions
from fxspace.controlpoints._edits import convert_keys as convert_keys
from fxspace.controlpoints._edits import edit_control_keys as edit_control_keys
from fxspace.controlpoints._edits import edit_displacements as edit_displacements
from fxspace.controlpoints._edits import edited_control_positions as edited_control_positions
from fxspace.controlpoints._edits import edited_vertices as edited_vertices
from fxspace.controlpoints._edits import effective_keys as effective_keys
from fxspace.controlpoints._edits import keyed_offsets as keyed_offsets
from fxspace.controlpoints._edits import load_edits as load_edits
from fxspace.controlpoints._edits import save_edits as save_edits
from fxspace.controlpoints._edits import segment_blend as segment_blend
from fxspace.controlpoints._fitting import FitResult as FitResult
from fxspace.controlpoints._fitting import refine_control_points as refine_control_points
from fxspace.controlpoints._fused_lasso import FusedLassoResult as FusedLassoResult
from fxspace.controlpoints._fused_lasso import flsa_objective as flsa_objective
from fxspace.controlpoints._fused_lasso import fused_lasso as fused_lasso
from fxspace.controlpoints._fused_lasso import fused_lasso_solve as fused_lasso_solve
from fxspace.controlpoints._fused_lasso import tv_denoise as tv_denoise
from fxspace.controlpoints._head import HEAD_COLOURS as HEAD_COLOURS
from fxspace.controlpoints._head import HeadModel as HeadModel
from fxspace.controlpoints._head import head_model as head_model
from fxspace.controlpoints._head import head_vertices as head_vertices
from fxspace.controlpoints._model import ControlPointFit as ControlPointFit
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
from fxspace.controlpoints._scene import SceneErrors as SceneErrors
from fxspace.controlpoints._scene import SceneFit as SceneFit
from fxspace.controlpoints._scene import SceneModel as SceneModel
from fxspace.controlpoints._scene import fit_scene as fit_scene
from fxspace.controlpoints._scene import linear_scene as linear_scene
from fxspace.controlpoints._scene import reconstruct_scene as reconstruct_scene
from fxspace.controlpoints._scene import scene_compression_ratio as scene_compression_ratio
from fxspace.controlpoints._scene import scene_errors as scene_errors
from fxspace.controlpoints._scene import scene_from_arrays as scene_from_arrays
from fxspace.controlpoints._scene import scene_storage_size as scene_storage_size
from fxspace.controlpoints._scene import scene_to_arrays as scene_to_arrays
from fxspace.controlpoints._scene import segment_of_frame as segment_of_frame
from fxspace.controlpoints._scene import thin_frames as thin_frames
from fxspace.controlpoints._segment import Segmentation as Segmentation
from fxspace.controlpoints._segment import choose_count as choose_count
from fxspace.controlpoints._segment import motion_summary as motion_summary
from fxspace.controlpoints._segment import segment_motion as segment_motion
from fxspace.controlpoints._segment import segments_from_boundaries as segments_from_boundaries

__all__ = [
    "HEAD_COLOURS",
    "HeadModel",
    "head_model",
    "head_vertices",
    "ControlPointModel",
    "blend_weights",
    "compression_ratio",
    "control_point_model",
    "edit_control_point",
    "fit_control_points",
    "ControlPointFit",
    "linear_interpolation",
    "reconstruct",
    "reconstruction_error",
    "residual_trajectories",
    "storage_size",
    "temporal_window",
    "Character",
    "character",
    "drive_character",
    "standin_character",
    "choose_count",
    "EditKey",
    "FaceKey",
    "anchor_offsets",
    "anchor_vertex",
    "check_face_keys",
    "convert_keys",
    "edit_displacements",
    "edited_control_positions",
    "edited_vertices",
    "segment_blend",
    "apply_edits",
    "control_positions",
    "edit_control_keys",
    "effective_keys",
    "keyed_offsets",
    "load_edits",
    "save_edits",
    "SceneErrors",
    "SceneFit",
    "SceneModel",
    "fit_scene",
    "linear_scene",
    "reconstruct_scene",
    "scene_compression_ratio",
    "scene_errors",
    "scene_storage_size",
    "segment_of_frame",
    "scene_to_arrays",
    "scene_from_arrays",
    "thin_frames",
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
