"""Inverse kinematics for linear-blend-skinned meshes (Park, Kang & Kwon), one import.

The implementation lives in private modules: :mod:`fxspace.mesh._ik_model` (the model and
its forward pass, eqs. (1)-(7)), :mod:`fxspace.mesh._ik_gradients` (naive eq. (9),
factored eq. (13), autodiff; the Jacobian), :mod:`fxspace.mesh._ik_regularizers` (joint
prior, limits, normal constraint) and :mod:`fxspace.mesh._ik_solvers` (LM, BFGS,
optimistix, Adam). This module re-exports them under their historical names.

Example:

```python
from fxspace.mesh._ik import ik_model, solve_ik
res = solve_ik(ik_model(mesh, markers), targets)
```
"""

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
from fxspace.mesh._ik_regularizers import ik_regularization as ik_regularization
from fxspace.mesh._ik_regularizers import marker_normals as marker_normals
from fxspace.mesh._ik_solvers import DEFAULT_METHOD as DEFAULT_METHOD
from fxspace.mesh._ik_solvers import METHODS as METHODS
from fxspace.mesh._ik_solvers import _flat as _flat
from fxspace.mesh._ik_solvers import _unflat as _unflat
from fxspace.mesh._ik_solvers import solve_ik as solve_ik
from fxspace.mesh._ik_solvers import track_ik as track_ik

__all__ = [
    "IKModel",
    "IKForward",
    "IKResult",
    "IK_STATUS",
    "IKRegularization",
    "ik_model",
    "ik_forward",
    "ik_markers",
    "ik_residuals",
    "ik_objective",
    "ik_gradient_naive",
    "ik_gradient_factored",
    "ik_gradient_autodiff",
    "gradient_naive_from_forward",
    "gradient_factored_from_forward",
    "value_and_gradient",
    "ik_jacobian",
    "ik_normal_equations",
    "ik_regularization",
    "marker_normals",
    "solve_ik",
    "track_ik",
    "METHODS",
    "DEFAULT_METHOD",
    "GRADIENTS",
]
