"""Landmark geodesics and landmark MDS (de Silva & Tenenbaum 2004, "Sparse multidimensional
scaling using landmark points"; Kim & Jung §3.2–3.3 at scale).

Instead of all T × T geodesics, only the ``L ≪ T`` rows from landmark frames are computed
(memory O(T·L)):

1. **landmarks** by max-min (farthest point) on the graph: each new landmark is the frame
   farthest (in geodesic distance) from the landmarks chosen so far; the single-source
   shortest paths computed on the way are the landmark geodesics themselves;
2. **landmark MDS**: classical MDS of the ``L × L`` squared geodesics ``Δ``,
   ``B = −½ J Δ J = V Λ Vᵀ``, landmark coordinates ``V_k Λ_k^{1/2}``;
3. **distance-based triangulation** (out-of-sample placement, de Silva & Tenenbaum eq. 3):
   a frame with squared geodesics ``δ_a`` to the landmarks sits at

       x_a = −½ L_k^# (δ_a − δ_μ),   L_k^# = Λ_k^{−1/2} V_kᵀ,   δ_μ = mean column of Δ,

   which returns a landmark's own coordinates, and equals classical MDS when every frame
   is a landmark.

Shortest paths run either on the host (``scipy.sparse.csgraph.dijkstra``, O(L·E log T))
or as a jit-compiled Bellman–Ford relaxation of all landmark rows at once (O(L·T·K) per
sweep, as many sweeps as the longest shortest path has edges; accelerator friendly).
Under ``jax.distributed`` the landmarks are split over the processes and gathered. With
``batch`` the max-min landmarks are picked a round at a time and each round's rows run in
parallel, here or as Dask tasks (`._landmark_rounds`).
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import checked
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.expression._landmark_rounds import Rows, check_batch, rounds
from fxspace.expression._mds import MDSResult, _fix_signs, double_centre
from fxspace.expression._row_workers import for_graph
from fxspace.expression._sparse import (
    NeighbourGraph,
    check_sparse_connected,
    dijkstra_csr,
    neighbourhood_graph,
)
from fxspace.results import result_from_flags

__all__ = [
    "LandmarkGeodesics",
    "LandmarkBasis",
    "farthest_point_landmarks",
    "landmark_geodesics",
    "landmark_basis",
    "place_frames",
    "landmark_mds",
    "landmark_score",
]

PathMethod = Literal["auto", "dijkstra", "relax"]


class LandmarkGeodesics(NamedTuple):
    """Geodesic distances from landmark frames to every frame (memory O(T·L)).

    - `distances`: ``(L, T)``; ``distances[l, t]`` is the geodesic from frame
      ``landmarks[l]`` to frame ``t`` (``inf`` if unreachable).
    - `landmarks`: ``(L,)`` int32 frame indices.
    """

    distances: Float[Array, "L n"]
    landmarks: Int[Array, " L"]


class LandmarkBasis(NamedTuple):
    """Landmark MDS of the ``L × L`` landmark geodesics (what out-of-sample placement needs).

    - `pinv`: ``(dim, L)`` pseudo-inverse transpose ``L_k^# = Λ_k^{−1/2} V_kᵀ``.
    - `mean_sq`: ``(L,)`` mean squared geodesic ``δ_μ`` of each landmark.
    - `eigenvalues`: ``(dim,)`` top eigenvalues of ``B`` (descending).
    """

    pinv: Float[Array, "dim L"]
    mean_sq: Float[Array, " L"]
    eigenvalues: Float[Array, " dim"]


def _check_graph(graph: NeighbourGraph) -> None:
    if not isinstance(graph, NeighbourGraph):
        raise FxspaceError(
            f"graph must be a NeighbourGraph (see neighbourhood_graph), got {type(graph)}"
        )


@partial(jax.jit, static_argnames=("max_steps",))
def _relax(indices: Array, weights: Array, sources: Array, max_steps: int) -> tuple[Array, Array]:
    """Bellman–Ford from every source at once on a padded adjacency list (undirected)."""
    n, K = indices.shape
    L = sources.shape[0]
    D0 = jnp.full((L, n), jnp.inf, weights.dtype).at[jnp.arange(L), sources].set(0)

    def sweep(D):
        def body(k, acc):
            return jnp.minimum(acc, D[:, indices[:, k]] + weights[None, :, k])

        return jax.lax.fori_loop(0, K, body, D)

    def cond(state):
        _, changed, step = state
        return changed & (step < max_steps)

    def step(state):
        D, _, s = state
        new = sweep(D)
        return new, jnp.any(new < D), s + 1

    D, _, steps = jax.lax.while_loop(cond, step, (D0, jnp.bool_(True), jnp.int32(0)))
    return D, steps


def _rows(graph: NeighbourGraph, sources: np.ndarray, method: str, csr=None) -> np.ndarray:
    """Shortest-path rows from `sources` ``(L, T)`` on the host or with the relaxation.

    `csr` is ``dijkstra_csr(graph)`` when the caller runs many single sources (converted and
    checked once; a symmetric graph runs scipy's directed search, half the work)."""
    if method == "auto":
        method = "dijkstra" if jax.default_backend() == "cpu" else "relax"
    if method == "dijkstra":
        from scipy.sparse.csgraph import dijkstra

        mat, directed = dijkstra_csr(graph) if csr is None else csr
        D = dijkstra(mat, directed=directed, indices=np.asarray(sources))
        return np.atleast_2d(D).astype(np.asarray(graph.weights).dtype)
    if method == "relax":
        n = graph.indices.shape[0]
        D, _ = _relax(graph.indices, graph.weights, jnp.asarray(sources, jnp.int32), n)
        return np.asarray(D)
    raise FxspaceError(f"method must be 'auto', 'dijkstra' or 'relax', got {method!r}")


def _distributed_rows(graph: NeighbourGraph, sources: np.ndarray, method: str) -> np.ndarray:
    """Rows split round-robin over the ``jax.distributed`` processes, then gathered."""
    nproc = jax.process_count()
    if nproc == 1:
        return _rows(graph, sources, method)
    from jax.experimental import multihost_utils

    me = jax.process_index()
    per = -(-len(sources) // nproc)
    padded = np.concatenate([sources, np.repeat(sources[-1:], per * nproc - len(sources))])
    mine = _rows(graph, padded[me::nproc], method)
    every = np.asarray(multihost_utils.process_allgather(mine))  # (nproc, per, T)
    out = np.empty((per * nproc, mine.shape[1]), mine.dtype)
    for p in range(nproc):
        out[p::nproc] = every[p]
    return out[: len(sources)]


def landmark_geodesics(
    graph: NeighbourGraph, landmarks: Int[Array, " L"], method: PathMethod = "auto"
) -> LandmarkGeodesics:
    """Geodesic distances from the given landmark frames to every frame.

    **Arguments:**

    - `graph`: a `fxspace.expression.NeighbourGraph`.
    - `landmarks`: ``(L,)`` frame indices.
    - `method`: ``"dijkstra"`` (host, scipy's csgraph), ``"relax"`` (jit Bellman–Ford of all
      rows at once; GPUs) or ``"auto"`` (dijkstra on a CPU, relax otherwise).

    Under ``jax.distributed`` (more than one process) the landmarks are split over the
    processes and the rows gathered, so every process returns the same array.

    **Returns:** `LandmarkGeodesics` with ``(L, T)`` distances (memory O(T·L)).
    """
    _check_graph(graph)
    lm = np.asarray(landmarks, np.int64).reshape(-1)
    n = graph.num_frames
    if lm.size == 0 or lm.min() < 0 or lm.max() >= n:
        raise FxspaceError(f"landmarks must be a non-empty list of frames in [0, {n})")
    D = _distributed_rows(graph, lm, method)
    return LandmarkGeodesics(jnp.asarray(D), jnp.asarray(lm, jnp.int32))


def _row_runner(graph: NeighbourGraph, method: str, csr, client):
    """``run(sources) -> rows`` for the rounds: scipy's Dijkstra a task a row (here or on
    the client), or the relaxation of a round's rows at once."""
    if csr is None:
        return lambda src: list(_rows(graph, np.asarray(src), "relax"))
    if method == "auto" and jax.default_backend() != "cpu":
        return lambda src: list(_rows(graph, np.asarray(src), "relax"))
    workers = for_graph(graph, dijkstra_csr) if client is None else None
    return Rows(csr[0], csr[1], np.asarray(graph.weights).dtype, client, workers)


def farthest_point_landmarks(
    graph: NeighbourGraph, num: int, start: int | None = None, method: PathMethod = "auto",
    *, batch: int | None = None, client=None,
) -> LandmarkGeodesics:  # fmt: skip
    """Choose ``num`` landmarks by max-min (farthest point) geodesic distance on the graph.

    The first landmark is the frame farthest from `start` (default frame 0), each next
    one the frame farthest from all landmarks so far (de Silva & Tenenbaum §4: max-min
    landmarks spread over the whole data and give stable triangulation). Costs ``num``
    single-source shortest paths, whose rows are returned, so no second pass is needed.

    **Arguments:**

    - `graph`: a `NeighbourGraph`; `num`: landmarks L; `start`: the frame the first
      landmark is farthest from; `method`: as in `landmark_geodesics`.
    - `batch`: pick this many landmarks a round and compute their rows in parallel
      (`fxspace.expression._landmark_rounds`: exact max-min for the first `batch`, then
      max-min on a triangle-inequality lower bound within a round; ``batch=1`` is the
      sequential result). ``None`` (default): one landmark after another, exact max-min.
    - `client`: a ``dask.distributed.Client``: each round's rows run as Dask tasks (one
      Dijkstra each, the graph sent to every worker once); needs `batch`. The landmarks
      and rows are those of ``client=None``, bit for bit.

    **Raises:** `fxspace.errors.DisconnectedGraphError` if the graph is disconnected.

    **Returns:** `LandmarkGeodesics` (landmarks in the order chosen).
    """
    _check_graph(graph)
    n = graph.num_frames
    if not 1 <= num <= n:
        raise FxspaceError(f"num must be in [1, {n}], got {num}")
    s = 0 if start is None else int(start)
    if not 0 <= s < n:
        raise FxspaceError(f"start must be a frame in [0, {n}), got {start}")
    batch = check_batch(batch, client, method, n)
    if client is not None:
        method = "dijkstra"  # the workers run scipy's Dijkstra; so does this process
    csr = dijkstra_csr(graph) if method != "relax" else None
    d0 = _rows(graph, np.array([s]), method, csr)[0]
    if not np.all(np.isfinite(d0)):
        n_unreached = int(np.sum(~np.isfinite(d0)))
        raise DisconnectedGraphError(
            f"the neighbourhood graph is disconnected: {n_unreached} of {n} frames are not "
            f"reachable from frame {s}; raise k or the threshold, or drop the isolated frames"
        )
    if batch is not None:
        run = _row_runner(graph, method, csr, client)
        lm, rows = rounds(int(np.argmax(d0)), num, batch, n, run)
        return LandmarkGeodesics(jnp.asarray(np.stack(rows)), jnp.asarray(lm, jnp.int32))
    lm = [int(np.argmax(d0))]
    rows = [_rows(graph, np.array(lm[-1:]), method, csr)[0]]
    mind = rows[0].copy()
    while len(lm) < num:
        nxt = int(np.argmax(mind))
        if mind[nxt] == 0:  # fewer distinct frames than landmarks asked for
            nxt = int(np.setdiff1d(np.arange(n), lm)[0])
        lm.append(nxt)
        rows.append(_rows(graph, np.array([nxt]), method, csr)[0])
        mind = np.minimum(mind, rows[-1])
    return LandmarkGeodesics(jnp.asarray(np.stack(rows)), jnp.asarray(lm, jnp.int32))


@checked
def landmark_basis(landmark_distances: Float[Array, "L L"], dim: int = 2) -> LandmarkBasis:
    """Classical MDS of the ``L × L`` landmark geodesics, kept for triangulation (eq. 3).

    Non-positive eigenvalues (non-Euclidean geodesics) give a zero axis, as in
    `fxspace.classical_mds`.
    """
    DL = jnp.asarray(landmark_distances)
    L = DL.shape[0]
    if DL.ndim != 2 or DL.shape[1] != L:
        raise FxspaceError(f"landmark_distances must be (L, L), got shape {DL.shape}")
    if not 1 <= dim < L:
        raise FxspaceError(f"dim must be in [1, L) = [1, {L}): add landmarks, got dim={dim}")
    DL = 0.5 * (DL + DL.T)
    w, V = jnp.linalg.eigh(double_centre(DL))
    lam = w[::-1][:dim]
    V = _fix_signs(V[:, ::-1][:, :dim])
    pos = lam > 0
    inv = jnp.where(pos, 1.0 / jnp.sqrt(jnp.where(pos, lam, 1.0)), 0.0)
    return LandmarkBasis((V * inv[None, :]).T, jnp.mean(DL * DL, axis=0), lam)


@checked
def place_frames(basis: LandmarkBasis, distances: Float[Array, "... L"]) -> Float[Array, "... dim"]:
    """Out-of-sample placement: ``x_a = −½ L_k^# (δ_a − δ_μ)`` from geodesics to landmarks.

    **Arguments:** `basis` from `landmark_basis`; `distances` ``(..., L)`` geodesic
    distances of each frame to the landmarks (in the landmark order of the basis).

    **Returns:** ``(..., dim)`` coordinates; a landmark is placed at its own coordinates.
    """
    d = jnp.asarray(distances)
    mean_sq = jnp.reshape(basis.mean_sq, (1,) * (d.ndim - 1) + (-1,))
    return -0.5 * (d * d - mean_sq) @ basis.pinv.T


@checked
def landmark_mds(geodesics: LandmarkGeodesics, dim: int = 2) -> MDSResult:
    """Landmark MDS of every frame (de Silva & Tenenbaum 2004), O(T·L·dim + L³).

    **Arguments:** `geodesics` from `landmark_geodesics` or
    `farthest_point_landmarks`; `dim` the embedding dimension (< L).

    **Returns:** `fxspace.expression.MDSResult` — the same type as
    `fxspace.classical_mds`, which it equals (up to float error) when every frame is a
    landmark; ``num_steps`` is 0 (dense ``eigh`` of the ``L × L`` matrix).

    **Example:**

    ```python
    geo = fx.farthest_point_landmarks(fx.neighbourhood_graph(F, k=10), 128)
    mds = fx.landmark_mds(geo, dim=2)
    ```
    """
    D = jnp.asarray(geodesics.distances)
    lm = jnp.asarray(geodesics.landmarks)
    if not bool(jnp.all(jnp.isfinite(D))):
        raise DisconnectedGraphError(
            "landmark geodesics contain inf: the graph is disconnected; raise k or the "
            "threshold, or drop the isolated frames"
        )
    if not 1 <= dim < D.shape[0]:
        raise FxspaceError(f"dim must be in [1, L) = [1, {D.shape[0]}): add landmarks")
    return _landmark_mds(D, lm, dim)


@partial(jax.jit, static_argnames=("dim",))
def _landmark_mds(D: Array, lm: Array, dim: int) -> MDSResult:
    basis = landmark_basis(D[:, lm], dim)
    X = place_frames(basis, D.T)
    ok = jnp.all(jnp.isfinite(X)) & jnp.all(jnp.isfinite(basis.eigenvalues))
    result = result_from_flags(converged=True, nonfinite_output=~ok)
    return MDSResult(X, basis.eigenvalues, jnp.zeros((), jnp.int32), result)


@checked
@jax.jit
def landmark_score(geodesics: LandmarkGeodesics, embedding: Float[Array, "n dim"]) -> Array:
    """Pearson r between landmark-to-frame geodesics and embedded distances (O(T·L)).

    The seed paper's quality criterion (`fxspace.pearson_score`) over the ``L × T``
    landmark–frame pairs instead of all ``T²/2`` pairs (self pairs excluded).
    """
    D = jnp.asarray(geodesics.distances)
    Y = jnp.asarray(embedding)
    lm = geodesics.landmarks
    diff = Y[lm][:, None, :] - Y[None, :, :]
    sq = jnp.sum(diff * diff, axis=-1)
    E = jnp.sqrt(jnp.maximum(sq, 0.0))
    mask = lm[:, None] != jnp.arange(Y.shape[0])[None, :]
    cnt = jnp.sum(mask)
    mx = jnp.sum(jnp.where(mask, D, 0.0)) / cnt
    my = jnp.sum(jnp.where(mask, E, 0.0)) / cnt
    dx = jnp.where(mask, D - mx, 0.0)
    dy = jnp.where(mask, E - my, 0.0)
    return jnp.sum(dx * dy) / jnp.sqrt(jnp.sum(dx * dx) * jnp.sum(dy * dy))


def landmark_space(
    features: Float[Array, "n p"],
    threshold: float | None,
    dim: int = 2,
    landmarks: int = 256,
    neighbours: int = 32,
    method: PathMethod = "auto",
) -> tuple[NeighbourGraph, LandmarkGeodesics, MDSResult, Array]:
    """The landmark route of `fxspace.expression_space`: sparse graph → max-min
    landmarks → landmark MDS → landmark score (memory O(T·(K + L)))."""

    n = int(np.asarray(features).shape[0])
    g = neighbourhood_graph(features, k=min(neighbours, n - 1), threshold=threshold)
    check_sparse_connected(g)
    geo = farthest_point_landmarks(g, min(landmarks, n), method=method)
    mds = landmark_mds(geo, dim)
    return g, geo, mds, landmark_score(geo, mds.embedding)
