"""The expression space in one call: markers → features → graph → geodesics → 2-D."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._features import distance_features, pairwise_distances
from ._geodesic import Geodesics, check_connected, epsilon_graph, geodesic_distances
from ._mds import MDSResult, classical_mds, pearson_score

__all__ = ["ExpressionSpace", "expression_space"]


class ExpressionSpace(NamedTuple):
    """Every stage of the expression space of one threshold."""

    features: Float[Array, "n p"]
    pairwise: Float[Array, "n n"]
    graph: Float[Array, "n n"]
    geodesics: Geodesics
    mds: MDSResult
    score: Array
    threshold: float

    @property
    def embedding(self) -> Float[Array, "n dim"]:
        return self.mds.embedding


def expression_space(
    positions: Float[Array, "n markers 3"] | None,
    threshold: float,
    dim: int = 2,
    features: Float[Array, "n p"] | None = None,
) -> ExpressionSpace:
    """Build the expression space of marker frames at threshold ε (Kim & Jung §3).

    Pass ``positions`` (``(n, M, 3)``, no NaN: see :func:`clean_frames`) or precomputed
    ``features``. Raises :class:`DisconnectedGraphError` (with the component count and the
    smallest connecting ε) when the ε-graph is disconnected.
    """
    F = distance_features(positions) if features is None else jnp.asarray(features)
    P = pairwise_distances(F)
    W = epsilon_graph(P, threshold)
    check_connected(W, P)
    geo = geodesic_distances(W)
    mds = classical_mds(geo.distances, dim=dim)
    r = pearson_score(geo.distances, mds.embedding)
    return ExpressionSpace(F, P, W, geo, mds, r, float(threshold))
