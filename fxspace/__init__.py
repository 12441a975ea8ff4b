"""fxspace: a JAX research framework for motion-capture-driven facial and character animation.

**What the top level re-exports (the one rule):**

1. Every subpackage and shared module as an attribute (`fx.cluster`, `fx.io`,
   `fx.results` …).
2. The main entry points and result/data types of the *numerical* subpackages
   (`cluster`, `expression`, `navigation`, `controlpoints`, `mesh`, `motion`) — the
   stable names of DESIGN.md and their companions — plus the result vocabulary
   (`RESULTS`) and the error types, each listed explicitly below and each the same
   object as on its subpackage's front (`fx.fuzzy_cmeans is fx.cluster.fuzzy_cmeans`).
   Every other public name lives on its subpackage only (`fx.cluster.kernel_kmeans_gram`,
   `fx.motion.advance_clock`); readers and writers stay under `fx.io`, generators
   under `fx.synthetic`, figures under `fx.plot`.
3. Subpackages that pull in a heavy or optional library — `plot` (matplotlib),
   `studio` (viser), `pipelines`, `datasets` and `cli` — load lazily on first
   attribute access (`fx.plot.plot_sweep(...)` works, but `import fxspace` itself
   imports no plotting, browser or sparse-graph library).
"""

import importlib as _importlib
from importlib import metadata as _metadata

from fxspace import _compile_cache as _compile_cache
from fxspace import cluster as cluster
from fxspace import config as config
from fxspace import controlpoints as controlpoints
from fxspace import data as data
from fxspace import errors as errors
from fxspace import expression as expression
from fxspace import face as face
from fxspace import io as io
from fxspace import mesh as mesh
from fxspace import motion as motion
from fxspace import navigation as navigation
from fxspace import results as results
from fxspace import rigid as rigid
from fxspace import rotations as rotations
from fxspace import runs as runs
from fxspace import synthetic as synthetic
from fxspace.cluster import FCMResult as FCMResult
from fxspace.cluster import KernelKMeansResult as KernelKMeansResult
from fxspace.cluster import fcm_memberships as fcm_memberships
from fxspace.cluster import fcm_objective as fcm_objective
from fxspace.cluster import fuzzy_cmeans as fuzzy_cmeans
from fxspace.cluster import gaussian_kernel as gaussian_kernel
from fxspace.cluster import kernel_kmeans as kernel_kmeans
from fxspace.cluster import kernel_kmeans_gram as kernel_kmeans_gram
from fxspace.cluster import kmeanspp_extend as kmeanspp_extend
from fxspace.cluster import kmeanspp_init as kmeanspp_init
from fxspace.cluster import median_gamma as median_gamma
from fxspace.controlpoints import ControlPointFit as ControlPointFit
from fxspace.controlpoints import ControlPointModel as ControlPointModel
from fxspace.controlpoints import EditKey as EditKey
from fxspace.controlpoints import FaceSurface as FaceSurface
from fxspace.controlpoints import FitResult as FitResult
from fxspace.controlpoints import FusedLassoResult as FusedLassoResult
from fxspace.controlpoints import SceneModel as SceneModel
from fxspace.controlpoints import Segmentation as Segmentation
from fxspace.controlpoints import apply_edits as apply_edits
from fxspace.controlpoints import blend_weights as blend_weights
from fxspace.controlpoints import compression_ratio as compression_ratio
from fxspace.controlpoints import control_point_model as control_point_model
from fxspace.controlpoints import control_positions as control_positions
from fxspace.controlpoints import edit_control_point as edit_control_point
from fxspace.controlpoints import face_surface as face_surface
from fxspace.controlpoints import fit_control_points as fit_control_points
from fxspace.controlpoints import fit_scene as fit_scene
from fxspace.controlpoints import flsa_objective as flsa_objective
from fxspace.controlpoints import fused_lasso as fused_lasso
from fxspace.controlpoints import fused_lasso_solve as fused_lasso_solve
from fxspace.controlpoints import linear_interpolation as linear_interpolation
from fxspace.controlpoints import linear_scene as linear_scene
from fxspace.controlpoints import load_edits as load_edits
from fxspace.controlpoints import motion_summary as motion_summary
from fxspace.controlpoints import rbf_deform as rbf_deform
from fxspace.controlpoints import rbf_transfer_matrix as rbf_transfer_matrix
from fxspace.controlpoints import reconstruct as reconstruct
from fxspace.controlpoints import reconstruct_scene as reconstruct_scene
from fxspace.controlpoints import reconstruction_error as reconstruction_error
from fxspace.controlpoints import refine_control_points as refine_control_points
from fxspace.controlpoints import residual_trajectories as residual_trajectories
from fxspace.controlpoints import save_edits as save_edits
from fxspace.controlpoints import scene_compression_ratio as scene_compression_ratio
from fxspace.controlpoints import scene_errors as scene_errors
from fxspace.controlpoints import scene_storage_size as scene_storage_size
from fxspace.controlpoints import segment_motion as segment_motion
from fxspace.controlpoints import segment_of_frame as segment_of_frame
from fxspace.controlpoints import segments_from_boundaries as segments_from_boundaries
from fxspace.controlpoints import storage_size as storage_size
from fxspace.controlpoints import temporal_window as temporal_window
from fxspace.controlpoints import thin_frames as thin_frames
from fxspace.controlpoints import tv_denoise as tv_denoise
from fxspace.errors import CorruptFileError as CorruptFileError
from fxspace.errors import DisconnectedGraphError as DisconnectedGraphError
from fxspace.errors import FxspaceError as FxspaceError
from fxspace.expression import ExpressionSpace as ExpressionSpace
from fxspace.expression import GapFill as GapFill
from fxspace.expression import Geodesics as Geodesics
from fxspace.expression import LandmarkGeodesics as LandmarkGeodesics
from fxspace.expression import MDSResult as MDSResult
from fxspace.expression import NeighbourGraph as NeighbourGraph
from fxspace.expression import SweepResult as SweepResult
from fxspace.expression import check_connected as check_connected
from fxspace.expression import choose_threshold as choose_threshold
from fxspace.expression import classical_mds as classical_mds
from fxspace.expression import clean_frames as clean_frames
from fxspace.expression import connected_components as connected_components
from fxspace.expression import connecting_threshold as connecting_threshold
from fxspace.expression import distance_features as distance_features
from fxspace.expression import epsilon_graph as epsilon_graph
from fxspace.expression import expression_space as expression_space
from fxspace.expression import farthest_point_landmarks as farthest_point_landmarks
from fxspace.expression import fill_gaps as fill_gaps
from fxspace.expression import floyd_warshall as floyd_warshall
from fxspace.expression import geodesic_distances as geodesic_distances
from fxspace.expression import graph_from_dense as graph_from_dense
from fxspace.expression import landmark_geodesics as landmark_geodesics
from fxspace.expression import landmark_mds as landmark_mds
from fxspace.expression import landmark_score as landmark_score
from fxspace.expression import neighbourhood_graph as neighbourhood_graph
from fxspace.expression import next_hops as next_hops
from fxspace.expression import pairwise_distances as pairwise_distances
from fxspace.expression import pearson_score as pearson_score
from fxspace.expression import place_frames as place_frames
from fxspace.expression import shortest_path as shortest_path
from fxspace.expression import threshold_grid as threshold_grid
from fxspace.expression import threshold_sweep as threshold_sweep
from fxspace.mesh import IKForward as IKForward
from fxspace.mesh import IKModel as IKModel
from fxspace.mesh import IKResult as IKResult
from fxspace.mesh import MarkerSet as MarkerSet
from fxspace.mesh import Pose as Pose
from fxspace.mesh import ik_forward as ik_forward
from fxspace.mesh import ik_gradient_autodiff as ik_gradient_autodiff
from fxspace.mesh import ik_gradient_factored as ik_gradient_factored
from fxspace.mesh import ik_gradient_naive as ik_gradient_naive
from fxspace.mesh import ik_jacobian as ik_jacobian
from fxspace.mesh import ik_markers as ik_markers
from fxspace.mesh import ik_model as ik_model
from fxspace.mesh import ik_normal_equations as ik_normal_equations
from fxspace.mesh import ik_objective as ik_objective
from fxspace.mesh import ik_residuals as ik_residuals
from fxspace.mesh import linear_blend_skinning as linear_blend_skinning
from fxspace.mesh import marker_influences as marker_influences
from fxspace.mesh import marker_positions as marker_positions
from fxspace.mesh import place_markers as place_markers
from fxspace.mesh import pose_from_local as pose_from_local
from fxspace.mesh import pose_vertices as pose_vertices
from fxspace.mesh import rest_pose as rest_pose
from fxspace.mesh import skin_local_pose as skin_local_pose
from fxspace.mesh import skinning_matrices as skinning_matrices
from fxspace.mesh import solve_ik as solve_ik
from fxspace.mesh import track_ik as track_ik
from fxspace.mesh import triangle_normals as triangle_normals
from fxspace.mesh import visible_triangles as visible_triangles
from fxspace.motion import DTWResult as DTWResult
from fxspace.motion import absolute_orientation as absolute_orientation
from fxspace.motion import dtw as dtw
from fxspace.motion import forward_kinematics as forward_kinematics
from fxspace.navigation import Hierarchy as Hierarchy
from fxspace.navigation import Level as Level
from fxspace.navigation import NavigationError as NavigationError
from fxspace.navigation import Playback as Playback
from fxspace.navigation import Route as Route
from fxspace.navigation import build_hierarchy as build_hierarchy
from fxspace.navigation import center_links as center_links
from fxspace.navigation import default_link_radius as default_link_radius
from fxspace.navigation import frame_path as frame_path
from fxspace.navigation import is_graph_walk as is_graph_walk
from fxspace.navigation import level_sizes as level_sizes
from fxspace.navigation import link_graph_connected as link_graph_connected
from fxspace.navigation import make_route as make_route
from fxspace.navigation import navigate as navigate
from fxspace.navigation import nearest_frames as nearest_frames
from fxspace.navigation import path_candidates as path_candidates
from fxspace.navigation import playback as playback
from fxspace.navigation import refine_route as refine_route
from fxspace.navigation import rigid_align as rigid_align
from fxspace.navigation import split_centers as split_centers
from fxspace.results import RESULTS as RESULTS

try:
    __version__ = _metadata.version("fxspace")
except _metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    __version__ = "0.0.0"

_compile_cache.configure_compile_cache()  # compile once per machine: FXSPACE_COMPILE_CACHE=DIR|off

# Heavy or optional subpackages: imported on first access (rule 3 of the module docstring).
_LAZY_SUBMODULES = ("plot", "studio", "pipelines", "datasets", "cli")


def __getattr__(name: str):
    if name in _LAZY_SUBMODULES:
        module = _importlib.import_module(f"fxspace.{name}")
        globals()[name] = module
        return module
    raise AttributeError(f"module 'fxspace' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY_SUBMODULES))
