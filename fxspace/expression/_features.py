"""Expression state: pairwise marker distances (Kim & Jung, §3.1).

A frame of ``M`` markers is represented by the ``P = M(M−1)/2`` distances between every
pair of markers, ``f_t = (‖x_i(t) − x_j(t)‖)_{i<j}``. The state is invariant to rigid head
motion (rotation + translation), so the expression space measures expression, not pose.
"""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace.errors import FxspaceError

__all__ = ["distance_features", "pairwise_distances", "marker_pairs", "clean_frames"]


def marker_pairs(n_markers: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays ``(i, j)`` of the pairs ``i < j`` in row-major order."""
    return np.triu_indices(n_markers, k=1)


def _safe_norm(x: Array, axis: int = -1) -> Array:
    """Euclidean norm whose gradient at 0 is 0 instead of NaN."""
    sq = jnp.sum(x * x, axis=axis)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def distance_features(
    positions: Float[Array, "frames markers 3"],
) -> Float[Array, "frames pairs"]:
    """Pairwise marker distances ``f_t[(i,j)] = ‖x_i(t) − x_j(t)‖`` for ``i < j`` (row-major).

    **Arguments:**
    - `positions`: ``(T, M, 3)`` marker positions; NaN marks a missing marker (use
      :func:`clean_frames` first: NaN propagates into every pair that touches it).

    **Returns:** ``(T, M(M−1)/2)`` distances, invariant to rigid motion of each frame.
    Cost O(T·M²). Differentiable (the gradient at a zero distance is taken as 0).
    """
    positions = jnp.asarray(positions)
    if positions.ndim != 3 or positions.shape[-1] != 3:
        raise FxspaceError(f"positions must have shape (frames, markers, 3), got {positions.shape}")
    if positions.shape[1] < 2:
        raise FxspaceError("positions needs at least 2 markers to form a distance")
    i, j = marker_pairs(positions.shape[1])
    return _safe_norm(positions[:, i, :] - positions[:, j, :])


def pairwise_distances(features: Float[Array, "frames dims"]) -> Float[Array, "frames frames"]:
    """Euclidean distance matrix ``P[s, t] = ‖f_s − f_t‖`` between feature vectors.

    Uses the Gram expansion on centred features (O(T²·P) in one matrix product), exact 0
    on the diagonal, symmetric, and differentiable (zero-distance gradients are 0).
    """
    F = jnp.asarray(features)
    if F.ndim != 2:
        raise FxspaceError(f"features must have shape (frames, dims), got {F.shape}")
    F = F - jnp.mean(F, axis=0, keepdims=True)
    sq = jnp.sum(F * F, axis=1)
    d2 = sq[:, None] + sq[None, :] - 2.0 * (F @ F.T)
    d2 = 0.5 * (d2 + d2.T)
    n = F.shape[0]
    off = ~jnp.eye(n, dtype=bool)
    pos = (d2 > 0) & off
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, d2, 1.0)), 0.0)


def clean_frames(positions: np.ndarray, policy: str = "drop") -> tuple[np.ndarray, np.ndarray]:
    """Handle frames with missing (NaN) markers before building features.

    **Arguments:**
    - `positions`: ``(T, M, 3)`` array, NaN where a marker is missing.
    - `policy`: ``"drop"`` removes frames with any NaN and warns how many;
      ``"raise"`` raises a ``FxspaceError`` naming how many frames are affected.

    **Returns:** ``(clean_positions, kept_frame_indices)``.
    """
    pos = np.asarray(positions)
    if pos.ndim != 3 or pos.shape[-1] != 3:
        raise FxspaceError(f"positions must have shape (frames, markers, 3), got {pos.shape}")
    if policy not in ("drop", "raise"):
        raise FxspaceError(f"policy must be 'drop' or 'raise', got {policy!r}")
    bad = ~np.isfinite(pos).all(axis=(1, 2))
    n_bad = int(bad.sum())
    kept = np.flatnonzero(~bad)
    if n_bad:
        if policy == "raise":
            raise FxspaceError(
                f"positions has {n_bad} of {len(pos)} frames with missing (NaN/inf) markers; "
                "fill the gaps or pass policy='drop' to drop those frames"
            )
        if n_bad == len(pos):
            raise FxspaceError("positions: every frame has a missing marker; nothing is left")
        warnings.warn(
            f"dropped {n_bad} of {len(pos)} frames with missing (NaN) markers", stacklevel=2
        )
    return pos[kept], kept
