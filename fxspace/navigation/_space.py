"""The navigable space in one call: expression space at a threshold + its FCM hierarchy.

Shared by the navigation pipeline and the browser navigator (one home for the wiring of
the library's chain into a hierarchy).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace.errors import FxspaceError
from fxspace.expression import (
    ExpressionSpace,
    connecting_threshold,
    distance_features,
    expression_space,
    pairwise_distances,
)
from fxspace.navigation._hierarchy import Hierarchy, build_hierarchy

__all__ = ["NavigationSpace", "navigation_space", "resolve_threshold"]


class NavigationSpace(NamedTuple):
    """An expression space, its hierarchy, the connecting ε and the ε used."""

    space: ExpressionSpace
    hierarchy: Hierarchy | None
    connecting_threshold: float
    threshold: float


def resolve_threshold(
    pairwise: Float[Array, "n n"], threshold: float | None, threshold_factor: float = 1.25
) -> tuple[float, float]:
    """``(ε, connecting ε)``: ``threshold`` when given, else ``threshold_factor`` × the smallest
    threshold that connects the graph. Raises ``FxspaceError`` when ε leaves it disconnected."""
    t_conn = float(connecting_threshold(pairwise))
    eps = float(threshold) if threshold else threshold_factor * t_conn
    if eps < t_conn:
        raise FxspaceError(
            f"threshold = {eps:.4g} leaves the graph disconnected; the smallest connecting "
            f"threshold is {t_conn:.4g}: raise it"
        )
    return eps, t_conn


def navigation_space(
    positions: Float[Array, "n markers 3"],
    threshold: float | None = None,
    *,
    threshold_factor: float = 1.25,
    dtype: str = "float32",
    key: Array | None = None,
    hierarchy: dict[str, Any] | None = None,
) -> NavigationSpace:
    """Expression space (with next hops, for paths) and, unless ``hierarchy is False``-y
    (``{}`` builds the defaults; ``None`` skips it), the FCM hierarchy over its 2-D embedding.

    **Arguments:**

    - `positions`: ``(n, M, 3)`` marker frames without NaN.
    - `threshold`: ε; ``None`` or 0 → `threshold_factor` × the connecting threshold.
    - `dtype`: ``"float32"`` or ``"float64"`` for the chain.
    - `key`: PRNG key of the FCM seeding.
    - `hierarchy`: keyword arguments of :func:`fxspace.build_hierarchy`.
    """
    if dtype not in ("float32", "float64"):
        raise FxspaceError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    X = jnp.asarray(positions, jnp.float32 if dtype == "float32" else jnp.float64)
    P = pairwise_distances(distance_features(X))
    eps, t_conn = resolve_threshold(P, threshold, threshold_factor)
    es = expression_space(None, eps, 2, pairwise=P)
    es = jax.block_until_ready(es)
    h = None
    if hierarchy is not None:
        h = build_hierarchy(
            es.embedding,
            es.geodesics,
            key=jax.random.PRNGKey(0) if key is None else key,
            **hierarchy,
        )
    return NavigationSpace(es, h, t_conn, eps)
