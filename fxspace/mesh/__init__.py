"""Mesh IK (Park, Kang & Kwon): skinned-mesh types, linear blend skinning, markers on
visible triangles, joint angles by the factored (two-loop) gradient.
"""

from fxspace.mesh._ik import IK_STATUS as IK_STATUS
from fxspace.mesh._ik import IKForward as IKForward
from fxspace.mesh._ik import IKModel as IKModel
from fxspace.mesh._ik import IKRegularization as IKRegularization
from fxspace.mesh._ik import IKResult as IKResult
from fxspace.mesh._ik import ik_forward as ik_forward
from fxspace.mesh._ik import ik_gradient_autodiff as ik_gradient_autodiff
from fxspace.mesh._ik import ik_gradient_factored as ik_gradient_factored
from fxspace.mesh._ik import ik_gradient_naive as ik_gradient_naive
from fxspace.mesh._ik import ik_jacobian as ik_jacobian
from fxspace.mesh._ik import ik_markers as ik_markers
from fxspace.mesh._ik import ik_model as ik_model
from fxspace.mesh._ik import ik_normal_equations as ik_normal_equations
from fxspace.mesh._ik import ik_objective as ik_objective
from fxspace.mesh._ik import ik_regularization as ik_regularization
from fxspace.mesh._ik import ik_residuals as ik_residuals
from fxspace.mesh._ik import marker_normals as marker_normals
from fxspace.mesh._ik import solve_ik as solve_ik
from fxspace.mesh._ik import track_ik as track_ik
from fxspace.mesh._markers import MarkerSet as MarkerSet
from fxspace.mesh._markers import marker_influences as marker_influences
from fxspace.mesh._markers import marker_positions as marker_positions
from fxspace.mesh._markers import place_markers as place_markers
from fxspace.mesh._markers import triangle_normals as triangle_normals
from fxspace.mesh._markers import visible_triangles as visible_triangles
from fxspace.mesh._skinning import Pose as Pose
from fxspace.mesh._skinning import linear_blend_skinning as linear_blend_skinning
from fxspace.mesh._skinning import pose_from_local as pose_from_local
from fxspace.mesh._skinning import pose_vertices as pose_vertices
from fxspace.mesh._skinning import rest_pose as rest_pose
from fxspace.mesh._skinning import skin_local_pose as skin_local_pose
from fxspace.mesh._skinning import skinning_matrices as skinning_matrices
from fxspace.mesh._types import Animation as Animation
from fxspace.mesh._types import AnimationChannel as AnimationChannel
from fxspace.mesh._types import LocalPose as LocalPose
from fxspace.mesh._types import SkinnedMesh as SkinnedMesh

__all__ = [
    "Animation",
    "AnimationChannel",
    "LocalPose",
    "SkinnedMesh",
    "IKForward",
    "IKModel",
    "IKResult",
    "IK_STATUS",
    "IKRegularization",
    "ik_regularization",
    "ik_forward",
    "ik_gradient_autodiff",
    "ik_gradient_factored",
    "ik_gradient_naive",
    "ik_jacobian",
    "ik_markers",
    "ik_model",
    "ik_normal_equations",
    "ik_objective",
    "ik_residuals",
    "marker_normals",
    "solve_ik",
    "track_ik",
    "MarkerSet",
    "marker_influences",
    "marker_positions",
    "place_markers",
    "triangle_normals",
    "visible_triangles",
    "Pose",
    "linear_blend_skinning",
    "pose_from_local",
    "pose_vertices",
    "rest_pose",
    "skin_local_pose",
    "skinning_matrices",
]
