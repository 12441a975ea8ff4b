"""The rig posed by a solve, where the capture is: the head the apps show and the
vertices an export carries.

A `FaceSolve` holds, per frame, expression weights ``w_t`` and the head's rigid motion
``(R_t, τ_t)`` in the rig's frame; a `Binding` holds the similarity ``y = s Q x + c``
from the capture's frame into the rig's and the fitted identity coefficients. The posed
mesh is

    y_t = R_t (n + Σ_i c_i I_i + Σ_k w_tk D_k) + τ_t            (rig frame and units)
    x_t = Qᵀ (y_t − c) / s                                       (capture frame and units)

so the capture's markers sit on it (each at its bound point, up to the solve's
residual). `posed_vertices` computes either, for any frames and any subset of the
vertices (``vertices``: a face-only view costs a third of the whole head).

Example:

```python
b = fx.face.bind_markers(rig, take.positions[0], take.names)
s = fx.face.solve_weights(rig, b, take.positions)
V = fx.face.posed_vertices(rig, b, s, frames=[0, 10])   # (2, N, 3), in the capture's frame
```
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace.errors import FxspaceError
from fxspace.face._bind import Binding
from fxspace.face._rig import Rig

__all__ = ["posed_vertices", "rest_vertices"]


def rest_vertices(rig: Rig, binding: Binding) -> Float[Array, "N 3"]:
    """The rig's neutral with the binding's identity coefficients applied (rig frame): the
    performer's head at rest."""
    n = jnp.asarray(rig.neutral)
    c = jnp.asarray(binding.identity, n.dtype)
    if c.shape[0] and rig.identity.shape[0] == c.shape[0]:
        n = n + jnp.einsum("i,inc->nc", c, jnp.asarray(rig.identity, n.dtype))
    return n


def posed_vertices(
    rig: Rig,
    binding: Binding,
    solve,
    frames=None,
    *,
    vertices=None,
    capture_frame: bool = True,
) -> Float[Array, "F N 3"]:
    """The rig's mesh at the solved weights and head motion (see the module docstring).

    **Arguments:** `rig`, `binding` (`bind_markers`), `solve` (`solve_weights`: one frame
    or a take); `frames`: the frames to pose (default all; an int gives one ``(N, 3)``
    mesh); `vertices`: the vertex indices to pose (default all); `capture_frame`: map
    back into the capture's frame and units (default) or stay in the rig's.

    **Returns:** ``(F, N, 3)`` (``(N, 3)`` for one frame, or a one-frame solve); NaN
    where the solve is NaN (a frame with too few markers seen).
    """
    if not isinstance(rig, Rig) or not isinstance(binding, Binding):
        raise FxspaceError("pass a fx.face.Rig and the fx.face.Binding from bind_markers")
    W = jnp.asarray(solve.weights)
    R = jnp.asarray(solve.rotation)
    tau = jnp.asarray(solve.translation)
    if W.shape[-1] != rig.num_shapes:
        raise FxspaceError(
            f"solve has {W.shape[-1]} weights per frame, the rig {rig.num_shapes} shapes: "
            "solve with this rig"
        )
    one = (frames is not None and np.ndim(frames) == 0) or (frames is None and W.ndim == 1)
    if W.ndim == 1:
        W, R, tau = W[None], R[None], tau[None]
    if frames is not None:
        idx = np.atleast_1d(np.asarray(frames))
        if not np.issubdtype(idx.dtype, np.integer) or idx.min() < -len(W) or idx.max() >= len(W):
            raise FxspaceError(f"frames must be frame indices in [0, {len(W)}); got {frames!r}")
        W, R, tau = W[idx], R[idx], tau[idx]
    base, D = rest_vertices(rig, binding), jnp.asarray(rig.deltas)
    if vertices is not None:
        vi = np.asarray(vertices)
        if vi.ndim != 1 or not np.issubdtype(vi.dtype, np.integer):
            raise FxspaceError("vertices must be a 1-D array of vertex indices")
        base, D = base[vi], D[:, vi]
    Y = base[None] + jnp.einsum("tk,knc->tnc", W.astype(D.dtype), D)
    Y = jnp.einsum("tij,tnj->tni", R, Y) + tau[:, None, :]
    if capture_frame:
        Q = jnp.asarray(binding.rotation, Y.dtype)
        c = jnp.asarray(binding.translation, Y.dtype).reshape(1, 1, 3)
        Y = (Y - c) @ Q / binding.scale
    return Y[0] if one else Y
