"""fxspace: a JAX research framework for motion-capture-driven facial and character animation.

Public API (stable names, see DESIGN.md) is re-exported here explicitly.
"""

from importlib import metadata as _metadata

from . import config as config
from . import data as data
from . import errors as errors
from . import io as io

# --- end hierarchy / navigation ---
# --- control points (issue 4) ---
# --- end control points ---
# --- motion (issue 5) ---
from . import motion as motion
from . import plot as plot
from . import runs as runs

# --- expression space (issue 2) ---
from ._expression import ExpressionSpace as ExpressionSpace
from ._expression import expression_space as expression_space

# --- end expression space ---
# --- hierarchy / navigation (issue 3) ---
from ._fcm import FCMResult as FCMResult
from ._fcm import fcm_memberships as fcm_memberships
from ._fcm import fcm_objective as fcm_objective
from ._fcm import fuzzy_cmeans as fuzzy_cmeans
from ._fcm import kmeanspp_init as kmeanspp_init
from ._features import clean_frames as clean_frames
from ._features import distance_features as distance_features
from ._features import pairwise_distances as pairwise_distances
from ._geodesic import Geodesics as Geodesics
from ._geodesic import check_connected as check_connected
from ._geodesic import connected_components as connected_components
from ._geodesic import connecting_threshold as connecting_threshold
from ._geodesic import epsilon_graph as epsilon_graph
from ._geodesic import floyd_warshall as floyd_warshall
from ._geodesic import geodesic_distances as geodesic_distances
from ._geodesic import next_hops as next_hops
from ._geodesic import shortest_path as shortest_path
from ._hierarchy import Hierarchy as Hierarchy
from ._hierarchy import Level as Level
from ._hierarchy import build_hierarchy as build_hierarchy
from ._hierarchy import center_links as center_links
from ._hierarchy import default_link_radius as default_link_radius
from ._hierarchy import level_sizes as level_sizes
from ._hierarchy import link_graph_connected as link_graph_connected
from ._hierarchy import nearest_frames as nearest_frames
from ._hierarchy import split_centers as split_centers

# --- end motion ---
# --- mesh IK (issue 6) ---
from ._ik import IKForward as IKForward
from ._ik import IKModel as IKModel
from ._ik import IKResult as IKResult
from ._ik import ik_forward as ik_forward
from ._ik import ik_gradient_autodiff as ik_gradient_autodiff
from ._ik import ik_gradient_factored as ik_gradient_factored
from ._ik import ik_gradient_naive as ik_gradient_naive
from ._ik import ik_jacobian as ik_jacobian
from ._ik import ik_markers as ik_markers
from ._ik import ik_model as ik_model
from ._ik import ik_objective as ik_objective
from ._ik import ik_residuals as ik_residuals
from ._ik import solve_ik as solve_ik
from ._ik import track_ik as track_ik
from ._markers_mesh import MarkerSet as MarkerSet
from ._markers_mesh import marker_influences as marker_influences
from ._markers_mesh import marker_positions as marker_positions
from ._markers_mesh import place_markers as place_markers
from ._markers_mesh import triangle_normals as triangle_normals
from ._markers_mesh import visible_triangles as visible_triangles
from ._mds import MDSResult as MDSResult
from ._mds import classical_mds as classical_mds
from ._mds import pearson_score as pearson_score
from ._navigate import NavigationError as NavigationError
from ._navigate import Route as Route
from ._navigate import frame_path as frame_path
from ._navigate import is_graph_walk as is_graph_walk
from ._navigate import make_route as make_route
from ._navigate import navigate as navigate
from ._navigate import path_candidates as path_candidates
from ._navigate import refine_route as refine_route
from ._playback import Playback as Playback
from ._playback import playback as playback
from ._playback import rigid_align as rigid_align
from ._skinning import Pose as Pose
from ._skinning import linear_blend_skinning as linear_blend_skinning
from ._skinning import pose_from_local as pose_from_local
from ._skinning import pose_vertices as pose_vertices
from ._skinning import rest_pose as rest_pose
from ._skinning import skin_local_pose as skin_local_pose
from ._skinning import skinning_matrices as skinning_matrices
from ._sweep import SweepResult as SweepResult
from ._sweep import choose_threshold as choose_threshold
from ._sweep import threshold_grid as threshold_grid
from ._sweep import threshold_sweep as threshold_sweep
from .errors import CorruptFileError as CorruptFileError
from .errors import DisconnectedGraphError as DisconnectedGraphError
from .errors import FxspaceError as FxspaceError
from .motion import DTWResult as DTWResult
from .motion import absolute_orientation as absolute_orientation
from .motion import dtw as dtw
from .motion import forward_kinematics as forward_kinematics

# --- end mesh IK ---

try:
    __version__ = _metadata.version("fxspace")
except _metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    __version__ = "0.0.0"
