"""The expression space in one call: markers → features → graph → geodesics → 2-D (Kim & Jung §3).

This module is the one home of the chain; the threshold sweep maps its kernel
`embed_graph` over thresholds, and every pipeline and app builds its space through
`expression_space`.
"""

from __future__ import annotations

import threading
import weakref
from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from fxspace._validate import check_choice, check_int, check_scalar
from fxspace.errors import FxspaceError
from fxspace.expression._features import distance_features, pairwise_distances
from fxspace.expression._geodesic import (
    Geodesics,
    check_connected,
    epsilon_graph,
    floyd_warshall,
    next_hops,
)
from fxspace.expression._landmark import LandmarkGeodesics, landmark_space
from fxspace.expression._mds import MDSResult, classical_mds, pearson_score
from fxspace.expression._missing import require_complete
from fxspace.expression._sparse import NeighbourGraph

__all__ = ["ExpressionSpace", "expression_space", "embed_graph", "GraphEmbedding"]

_LANDMARK_FROM = 5000  # frames; above this expression_space takes the landmark route


class GraphEmbedding(NamedTuple):
    """Output of `embed_graph`: geodesic distances, the MDS, Pearson r, connectivity."""

    distances: Float[Array, "n n"]
    mds: MDSResult
    score: Float[Array, ""]
    connected: Bool[Array, ""]


def embed_graph(
    graph: Float[Array, "n n"],
    dim: int = 2,
    method: Literal["auto", "scan", "blocked", "sharded"] = "auto",
    mds_method: Literal["auto", "eigh", "lobpcg"] = "auto",
    symmetric: bool | None = None,
) -> GraphEmbedding:
    """Geodesics (min-plus Floyd) → classical MDS → Pearson r of one ε-graph, branch-free.

    The kernel of the chain, shared by `expression_space` and
    `fxspace.threshold_sweep`. A disconnected graph is reported by ``connected =
    False`` and ``score = nan`` (the MDS then runs on the finite part only, so no ``inf``
    reaches the eigensolver). jit/vmap compatible; differentiable through the distances.
    ``symmetric``: as in `floyd_warshall` (``True`` under ``jit`` for an undirected graph
    runs the folded Floyd, half the work). Called outside ``jit`` it runs two compiled
    kernels (the Floyd, then MDS and r), which a sweep and the space of its ε share.
    """
    D = floyd_warshall(graph, method=method, symmetric=symmetric)
    mds, r, connected = _embed_distances(D, dim, mds_method)
    return GraphEmbedding(D, mds, r, connected)


@partial(jax.jit, static_argnames=("dim", "mds_method"))
def _embed_distances(D: Array, dim: int, mds_method: str):
    """``(mds, r, connected)`` of geodesic distances ``D`` (``inf``: disconnected)."""
    connected = jnp.all(jnp.isfinite(D))
    Dc = jnp.where(jnp.isfinite(D), D, 0.0)
    mds = classical_mds(Dc, dim=dim, method=mds_method)
    r = pearson_score(Dc, mds.embedding)
    nan = jnp.asarray(jnp.nan, r.dtype)
    return mds, jnp.where(connected, r, nan), connected


# The best-scoring connected embedding a threshold sweep computed, per pairwise matrix (a
# JAX array: immutable; held by a weak reference, so an id reused by another array is never
# taken for it): `expression_space` at that ε takes it instead of computing it again.
_SWEPT: dict[int, tuple[weakref.ref, tuple, GraphEmbedding]] = {}
_SWEPT_LOCK = threading.Lock()


def _remember(pairwise: Any, key: tuple, emb: GraphEmbedding) -> None:
    """Keep ``emb`` (``key``: ε, dim, method, mds_method) for ``pairwise`` if it scores
    higher than the one kept (a sweep's threads call this as each ε finishes)."""
    if not isinstance(pairwise, jax.Array) or isinstance(pairwise, jax.core.Tracer):
        return
    with _SWEPT_LOCK:
        for k in [k for k, (ref, _, _) in _SWEPT.items() if ref() is None]:
            del _SWEPT[k]
        held = _SWEPT.get(id(pairwise))
        if held is not None and held[0]() is pairwise and not emb.score > held[2].score:
            return
        _SWEPT[id(pairwise)] = (weakref.ref(pairwise), key, emb)


def _recall(pairwise: Any, key: tuple) -> GraphEmbedding | None:
    """The embedding `_remember`-ed for this very ``pairwise`` array and ``key``, else None."""
    with _SWEPT_LOCK:
        held = _SWEPT.get(id(pairwise))
    if held is None or held[0]() is not pairwise or held[1] != key:
        return None
    return held[2]


class ExpressionSpace(NamedTuple):
    """Every stage of the expression space of one threshold.

    ``geodesics.next_hop`` is ``None`` when the space was built with ``paths=False``.
    """

    features: Float[Array, "n p"] | None
    pairwise: Float[Array, "n n"] | None  # None on the landmark route
    graph: Float[Array, "n n"] | NeighbourGraph  # NeighbourGraph on the landmark route
    geodesics: Geodesics | LandmarkGeodesics  # (L, T) landmark rows on the landmark route
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
    *,
    pairwise: Float[Array, "n n"] | None = None,
    paths: bool = True,
    method: Literal["auto", "scan", "blocked", "sharded"] = "auto",
    mds_method: Literal["auto", "eigh", "lobpcg"] = "auto",
    route: Literal["auto", "dense", "landmark"] = "auto",
    landmarks: int = 256,
    neighbours: int = 32,
) -> ExpressionSpace:
    """Build the expression space of marker frames at threshold ε (Kim & Jung §3).

    **Arguments:**

    - `positions`: ``(n, M, 3)`` marker frames (no NaN: see `fxspace.clean_frames`),
      or ``None`` when `features` or `pairwise` is given.
    - `threshold`: ε, in the units of the state distance (mm for marker data).
    - `dim`: embedding dimension (2 in the paper).
    - `features`: precomputed ``(n, P)`` distance features.
    - `pairwise`: precomputed ``(n, n)`` state distances (e.g. shared with a sweep).
    - `paths`: also compute the next-hop matrix (needed for `fxspace.shortest_path`
      and navigation; skip it for a score or a figure).
    - `method`, `mds_method`: Floyd and eigensolver variants.
    - `route`: ``"dense"`` (T × T geodesics), ``"landmark"`` (de Silva & Tenenbaum 2004:
      sparse ε-graph capped at `neighbours` per frame, geodesics from `landmarks` max-min
      landmarks, landmark MDS; memory O(T·L); see `fxspace.landmark_mds`) or
      ``"auto"`` (landmark above 5000 frames unless `pairwise` is given). On the
      landmark route ``pairwise`` is ``None``, ``graph`` a
      `fxspace.expression.NeighbourGraph`, ``geodesics`` a
      `fxspace.expression.LandmarkGeodesics` and ``score`` the landmark r.

    **Returns:** an `ExpressionSpace`.

    **Raises:** `fxspace.errors.DisconnectedGraphError` (with the component count
    and the smallest connecting ε) when the ε-graph is disconnected.

    **Example:**

    ```python
    es = fx.expression_space(positions, 50.0)
    es.embedding, es.score
    ```
    """
    threshold = check_scalar(threshold, "threshold", low=0.0, low_open=True)
    dim = check_int(dim, "dim", low=1)
    check_choice(route, "route", ("auto", "dense", "landmark"))
    if pairwise is None:
        if features is None:
            require_complete(positions)  # names the missing markers and frames
        F = distance_features(positions) if features is None else jnp.asarray(features)
        if route == "landmark" or (route == "auto" and F.shape[0] > _LANDMARK_FROM):
            g, lgeo, lmds, r = landmark_space(F, threshold, dim, landmarks, neighbours)
            return ExpressionSpace(F, None, g, lgeo, lmds, r, float(threshold))
        P = pairwise_distances(F)
    else:
        if route == "landmark":
            raise FxspaceError("route='landmark' needs positions or features, not pairwise")
        F = None if features is None else jnp.asarray(features)
        P = jnp.asarray(pairwise)
    W = epsilon_graph(P, threshold)
    check_connected(W, P)
    # the sweep of these distances may hold this ε's embedding (`_remember`)
    emb = _recall(pairwise, (float(threshold), dim, method, mds_method))
    if emb is None:
        emb = embed_graph(W, dim, method=method, mds_method=mds_method)
    nxt = None
    if paths:
        D = jax.lax.stop_gradient(emb.distances)
        nxt = next_hops(W, D)
    geo = Geodesics(emb.distances, nxt)
    return ExpressionSpace(F, P, W, geo, emb.mds, emb.score, float(threshold))
