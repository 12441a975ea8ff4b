"""Mesh IK (Park, Kang & Kwon): skinned-mesh types, linear blend skinning, markers on
visible triangles, joint angles by the factored (two-loop) gradient, constraints as
residuals in every solver.

The paper's pipeline in three lines: markers on visible triangles are skinned points
(`place_markers`, `ik_model`); the gradient of ``E(θ) = Σ_k ‖p_k(θ) − t_k‖²`` is
factored into per-joint sums accumulated up the hierarchy (eq. (13),
`ik_gradient_factored`); a solver (`solve_ik`, `track_ik`) fits the pose per frame.

This is the subpackage's one public front; the implementation lives in private modules
(`_types`, `_skinning`, `_markers`, `_ik_model`, `_ik_gradients`, `_ik_constraints`,
`_ik_regularizers`, `_ik_problem`, `_ik_methods`, `_ik_solvers`, `_procedural`,
`_retarget`, `_retarget_inputs`, `_retarget_kinematics`, `_retarget_live`).

Example:

```python
import fxspace as fx
mesh = fx.io.read_gltf("CesiumMan.glb")
markers = fx.place_markers(mesh.vertices, mesh.faces, 50)
model = fx.ik_model(mesh, markers)
targets = fx.marker_positions(fx.mesh.animation_vertices(mesh, 0, 0.5), mesh.faces, markers)
res = fx.solve_ik(model, targets, solver=fx.mesh.LevenbergMarquardt(rtol=1e-3))
```
"""

from fxspace.mesh._ik_constraints import IKConstraints as IKConstraints
from fxspace.mesh._ik_constraints import JointLimits as JointLimits
from fxspace.mesh._ik_constraints import JointPrior as JointPrior
from fxspace.mesh._ik_constraints import NormalConstraint as NormalConstraint
from fxspace.mesh._ik_constraints import PlaneContact as PlaneContact
from fxspace.mesh._ik_constraints import (
    constrained_normal_equations as constrained_normal_equations,
)
from fxspace.mesh._ik_constraints import (
    constrained_value_and_gradient as constrained_value_and_gradient,
)
from fxspace.mesh._ik_constraints import constraint_residuals as constraint_residuals
from fxspace.mesh._ik_constraints import ik_constraints as ik_constraints
from fxspace.mesh._ik_constraints import joint_limits as joint_limits
from fxspace.mesh._ik_constraints import joint_prior as joint_prior
from fxspace.mesh._ik_constraints import marker_normals as marker_normals
from fxspace.mesh._ik_constraints import normal_constraint as normal_constraint
from fxspace.mesh._ik_constraints import plane_contact as plane_contact
from fxspace.mesh._ik_gradients import GRADIENTS as GRADIENTS
from fxspace.mesh._ik_gradients import (
    gradient_factored_from_forward as gradient_factored_from_forward,
)
from fxspace.mesh._ik_gradients import gradient_naive_from_forward as gradient_naive_from_forward
from fxspace.mesh._ik_gradients import ik_gradient_autodiff as ik_gradient_autodiff
from fxspace.mesh._ik_gradients import ik_gradient_factored as ik_gradient_factored
from fxspace.mesh._ik_gradients import ik_gradient_naive as ik_gradient_naive
from fxspace.mesh._ik_gradients import ik_jacobian as ik_jacobian
from fxspace.mesh._ik_gradients import ik_normal_equations as ik_normal_equations
from fxspace.mesh._ik_gradients import value_and_gradient as value_and_gradient
from fxspace.mesh._ik_methods import BFGS as BFGS
from fxspace.mesh._ik_methods import Adam as Adam
from fxspace.mesh._ik_methods import LevenbergMarquardt as LevenbergMarquardt
from fxspace.mesh._ik_methods import OptimistixGaussNewton as OptimistixGaussNewton
from fxspace.mesh._ik_methods import OptimistixLM as OptimistixLM
from fxspace.mesh._ik_model import IK_STATUS as IK_STATUS
from fxspace.mesh._ik_model import IKForward as IKForward
from fxspace.mesh._ik_model import IKModel as IKModel
from fxspace.mesh._ik_model import IKResult as IKResult
from fxspace.mesh._ik_model import ik_forward as ik_forward
from fxspace.mesh._ik_model import ik_markers as ik_markers
from fxspace.mesh._ik_model import ik_model as ik_model
from fxspace.mesh._ik_model import ik_objective as ik_objective
from fxspace.mesh._ik_model import ik_residuals as ik_residuals
from fxspace.mesh._ik_regularizers import IKRegularization as IKRegularization
from fxspace.mesh._ik_regularizers import (
    constraints_from_regularization as constraints_from_regularization,
)
from fxspace.mesh._ik_regularizers import ik_regularization as ik_regularization
from fxspace.mesh._ik_solvers import DEFAULT_METHOD as DEFAULT_METHOD
from fxspace.mesh._ik_solvers import METHODS as METHODS
from fxspace.mesh._ik_solvers import solve_ik as solve_ik
from fxspace.mesh._ik_solvers import solver_from_method as solver_from_method
from fxspace.mesh._ik_solvers import track_ik as track_ik
from fxspace.mesh._markers import MarkerSet as MarkerSet
from fxspace.mesh._markers import marker_influences as marker_influences
from fxspace.mesh._markers import marker_positions as marker_positions
from fxspace.mesh._markers import place_markers as place_markers
from fxspace.mesh._markers import triangle_normals as triangle_normals
from fxspace.mesh._markers import visible_triangles as visible_triangles
from fxspace.mesh._procedural import chain_mesh as chain_mesh
from fxspace.mesh._procedural import subdivide_mesh as subdivide_mesh
from fxspace.mesh._retarget import Retargeted as Retargeted
from fxspace.mesh._retarget import retarget as retarget
from fxspace.mesh._retarget_inputs import RetargetError as RetargetError
from fxspace.mesh._retarget_kinematics import joint_positions as joint_positions
from fxspace.mesh._retarget_live import LiveRetarget as LiveRetarget
from fxspace.mesh._retarget_live import live_retarget as live_retarget
from fxspace.mesh._skinning import Pose as Pose
from fxspace.mesh._skinning import SkinTables as SkinTables
from fxspace.mesh._skinning import ancestor_table as ancestor_table
from fxspace.mesh._skinning import animation_vertices as animation_vertices
from fxspace.mesh._skinning import linear_blend_skinning as linear_blend_skinning
from fxspace.mesh._skinning import pose_from_local as pose_from_local
from fxspace.mesh._skinning import pose_vertices as pose_vertices
from fxspace.mesh._skinning import rest_pose as rest_pose
from fxspace.mesh._skinning import rest_vertices as rest_vertices
from fxspace.mesh._skinning import skin_local_pose as skin_local_pose
from fxspace.mesh._skinning import skin_tables as skin_tables
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
    "constraints_from_regularization",
    "IKConstraints",
    "NormalConstraint",
    "PlaneContact",
    "JointLimits",
    "JointPrior",
    "ik_constraints",
    "normal_constraint",
    "plane_contact",
    "joint_limits",
    "joint_prior",
    "constraint_residuals",
    "constrained_value_and_gradient",
    "constrained_normal_equations",
    "LevenbergMarquardt",
    "BFGS",
    "Adam",
    "OptimistixLM",
    "OptimistixGaussNewton",
    "solver_from_method",
    "METHODS",
    "DEFAULT_METHOD",
    "GRADIENTS",
    "ik_forward",
    "ik_gradient_autodiff",
    "ik_gradient_factored",
    "ik_gradient_naive",
    "gradient_factored_from_forward",
    "gradient_naive_from_forward",
    "value_and_gradient",
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
    "subdivide_mesh",
    "chain_mesh",
    "Retargeted",
    "RetargetError",
    "retarget",
    "joint_positions",
    "LiveRetarget",
    "live_retarget",
    "Pose",
    "SkinTables",
    "skin_tables",
    "ancestor_table",
    "animation_vertices",
    "rest_vertices",
    "linear_blend_skinning",
    "pose_from_local",
    "pose_vertices",
    "rest_pose",
    "skin_local_pose",
    "skinning_matrices",
]
