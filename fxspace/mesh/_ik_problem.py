"""One frame's mesh-IK problem in scaled coordinates and the one loop every solver runs
(`fxspace.mesh.solve_ik`): ``z = (θ, τ / L)``, the objective, its gradient and normal
equations with the constraint blocks, and `_iterate` (after optimistix's ``iterate``:
``init``, ``step`` while not ``terminate``, ``postprocess``).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
from jaxtyping import Array

from fxspace.mesh._ik_constraints import (
    constrained_normal_equations,
    constrained_value_and_gradient,
)
from fxspace.mesh._skinning import Pose


def _flat(pose: Pose) -> Array:
    return jnp.concatenate([pose.angles.reshape(-1), pose.translation])


def _unflat(x: Array, nj: int) -> Pose:
    return Pose(x[: 3 * nj].reshape(nj, 3), x[3 * nj :])


class _Problem:
    """The data of one frame's solve, bundled for the solver loops (not a pytree: built
    inside the jitted function, never crosses a ``jit`` boundary)."""

    def __init__(self, model, cons, targets, init, normals):
        self.model, self.cons, self.targets = model, cons, targets
        self.init, self.normals = init, normals
        self.nj = model.ancestors.shape[0]
        self.target_norm = jnp.sqrt(jnp.sum(targets * targets))
        scale = model.length_scale
        self.sv = jnp.concatenate(
            [jnp.ones(3 * self.nj, targets.dtype), jnp.full(3, scale, targets.dtype)]
        )

    def abs_tolerance(self, atol: float) -> Array:
        return (atol * self.model.length_scale) ** 2 * self.targets.shape[0]

    def pose(self, z: Array) -> Pose:
        return _unflat(z * self.sv, self.nj)

    def value_and_grad(self, gradient: str, z: Array) -> tuple[Array, Array]:
        v, g = constrained_value_and_gradient(
            gradient, self.model, self.cons, self.pose(z), self.targets, self.init, self.normals
        )
        return v, _flat(g) * self.sv

    def normal_equations(self, z: Array) -> tuple[Array, Array, Array]:
        obj, g, h = constrained_normal_equations(
            self.model, self.cons, self.pose(z), self.targets, self.init, self.normals
        )
        sv = self.sv
        return obj, g * sv, h * (sv[:, None] * sv[None, :])


def _ftol(solver, pb: _Problem, obj: Array) -> Array:
    """The decrease of ``F`` below which a step counts as none: ``rtol · F``, floored at
    what rounding lets the dtype resolve. A residual ``r = p − t`` of positions of size
    ``|t|`` carries an error ``ε|t|`` (cancellation), so ``F = Σ r²`` is known to about
    ``2 ε Σ |r||t| ≤ 2 ε √F ‖t‖``. In float32 near a minimum that is far above
    ``1e-6 · F``: the steps there were rejected as rounding noise until the damping blew
    up (CesiumMan, 120 markers, from rest: 26 LM iterations and ``stalled`` in float32
    against 13.7 and ``successful`` in float64); in float64 the floor never binds."""
    eps = float(jnp.finfo(obj.dtype).eps)
    return jnp.maximum(solver.rtol * obj, 2.0 * eps * pb.target_norm * jnp.sqrt(obj))


def _diagonal(h: Array) -> Array:
    """``diag(h)`` as a strided slice (``jnp.diagonal`` is a gather with an index table)."""
    return h.reshape(-1)[:: h.shape[0] + 1]


class _Outcome(NamedTuple):
    """What `postprocess` hands back: the pose in scaled coordinates, the step count,
    the flags, and the objective at the end and at the start where the solver knows it
    without another forward pass (``None`` otherwise)."""

    z: Array
    steps: Array
    converged: Array
    stalled: Array
    objective: tuple[Array, Array] | None = None


class _Iterative(Protocol):
    """What `_iterate` needs of a solver (every one in ``_ik_methods`` has it; the
    ``Solver`` union of them is owned there, so this module imports none of them)."""

    max_steps: int

    def init(self, pb: _Problem, skip: Array) -> Any: ...
    def step(self, pb: _Problem, state: Any) -> Any: ...
    def terminate(self, state: Any) -> Array: ...
    def postprocess(self, pb: _Problem, state: Any, k: Array) -> _Outcome: ...


def _iterate(pb: _Problem, solver: _Iterative, skip) -> _Outcome:
    """The one loop of every IK solver (after optimistix's ``iterate``): ``state =
    solver.init(pb, skip)``, then ``solver.step`` while fewer than ``max_steps`` steps
    were taken and ``solver.terminate(state)`` is false, then ``solver.postprocess``.
    ``skip`` (non-finite input) starts the loop finished: no ``lax.cond`` (XLA:CPU runs a
    conditional's branch as a task on its thread pool, a thread hop per call)."""
    state = solver.init(pb, jnp.asarray(skip, bool))

    def cond(c):
        k, s = c
        return (k < solver.max_steps) & ~solver.terminate(s)

    def body(c):
        k, s = c
        return k + 1, solver.step(pb, s)

    k, state = jax.lax.while_loop(cond, body, (jnp.asarray(0, jnp.int32), state))
    return solver.postprocess(pb, state, k)
