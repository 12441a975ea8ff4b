"""Hierarchy, links and routes at scale: no ``T × T`` matrix (seed paper §4 past 10⁴ frames).

The dense navigation (`fxspace.build_hierarchy`, `fxspace.make_route`) walks a
``T × T`` next-hop matrix. Here the same steps run on the sparse
`fxspace.expression.NeighbourGraph`:

- **levels**: fuzzy c-means with sparse memberships
  (`fxspace.cluster.sparse_fuzzy_cmeans`) at c0·2^l centres; each centre is shown
  as its nearest frame;
- **links**: centres i—j are linked when the shortest graph path between their frames
  passes no frame within 2-D distance ρ of any other centre (the seed's rule), tested
  for each centre's `near` nearest centres in 2-D, with one single-source Dijkstra (with
  predecessors) per centre; components left apart are bridged by their geodesically
  nearest centres, as in the dense hierarchy;
- **routes**: key frames joined by shortest graph paths
  (`fxspace.sparse_shortest_path`).

Memory O(T·(K + B)) for a batch of B centres' Dijkstra rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, Float

from fxspace.cluster import SparseFCMResult, sparse_fuzzy_cmeans
from fxspace.errors import FxspaceError
from fxspace.expression import NeighbourGraph, sparse_shortest_path, to_scipy

__all__ = ["SparseLevel", "sparse_levels", "sparse_links", "sparse_hierarchy", "sparse_route"]


class SparseLevel(NamedTuple):
    """One level of the hierarchy at scale.

    - `n_clusters`: c; `centers`: ``(c, 2)``; `center_frames`: ``(c,)`` nearest frames.
    - `links`, `bridges`: ``(c, c)`` symmetric bool (bridges ⊂ links).
    - `fcm`: the `fxspace.cluster.SparseFCMResult` of the level.
    """

    n_clusters: int
    centers: np.ndarray
    center_frames: np.ndarray
    links: np.ndarray
    bridges: np.ndarray
    fcm: SparseFCMResult


def _nearest_frames(Y: np.ndarray, centers: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return cKDTree(Y).query(centers, k=1)[1].astype(np.int64)


def sparse_links(
    graph: NeighbourGraph,
    embedding: Float[Array, "T 2"],
    center_frames: np.ndarray,
    rho: float | None = None,
    near: int = 6,
    batch: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """Links between centres on the sparse graph (seed §4 rule, see the module docstring).

    **Arguments:** `graph`; `embedding` ``(T, 2)``; `center_frames` ``(c,)``; `rho` (default
    half the median nearest-centre spacing); `near` candidate neighbours per centre;
    `batch` centres per Dijkstra call (memory ``batch × T``).

    **Returns:** ``(links, bridges)``, ``(c, c)`` symmetric bool, False diagonal.
    """
    from scipy.sparse.csgraph import connected_components, dijkstra
    from scipy.spatial import cKDTree

    Y = np.asarray(embedding, np.float64)
    cf = np.asarray(center_frames, np.int64)
    c = len(cf)
    links = np.zeros((c, c), bool)
    bridges = np.zeros((c, c), bool)
    if c < 2:
        return links, bridges
    pos = Y[cf]
    tree = cKDTree(pos)
    if rho is None:
        nn = tree.query(pos, k=2)[0][:, 1]
        rho = 0.5 * float(np.median(nn[nn > 0])) if np.any(nn > 0) else 0.0
    kq = min(near + 1, c)
    cand = tree.query(pos, k=kq)[1][:, 1:]
    csr = to_scipy(graph)
    Dcc = np.full((c, c), np.inf)
    for s in range(0, c, batch):
        rows = np.arange(s, min(s + batch, c))
        d, pred = dijkstra(csr, directed=False, indices=cf[rows], return_predecessors=True)
        Dcc[rows] = d[:, cf]
        for r, i in enumerate(rows):
            for j in cand[i]:
                if links[i, j] or not np.isfinite(d[r, cf[j]]):
                    continue
                path = [cf[j]]
                while path[-1] != cf[i]:
                    path.append(pred[r, path[-1]])
                dist, idx = tree.query(Y[path], k=min(3, c), distance_upper_bound=rho)
                other = np.isfinite(dist) & (idx != i) & (idx != j) & (idx < c)
                other &= cf[np.minimum(idx, c - 1)] != cf[i]
                other &= cf[np.minimum(idx, c - 1)] != cf[j]
                if not other.any():
                    links[i, j] = links[j, i] = True
    np.fill_diagonal(Dcc, np.inf)
    while True:
        n_comp, lab = connected_components(links, directed=False)
        if n_comp == 1:
            break
        sizes = np.bincount(lab)
        inside = lab == int(np.argmin(sizes))
        sub = Dcc[np.ix_(inside, ~inside)]
        if not np.isfinite(sub).any():
            break  # the frame graph itself is disconnected
        a, b = np.unravel_index(np.argmin(sub), sub.shape)
        i, j = np.flatnonzero(inside)[a], np.flatnonzero(~inside)[b]
        links[i, j] = links[j, i] = bridges[i, j] = bridges[j, i] = True
    return links, bridges


def sparse_levels(c0: int, levels: int, n_frames: int) -> tuple[int, ...]:
    """c0, 2c0, 4c0, … (at most `levels`, each at most the number of frames)."""
    return tuple(c for c in (c0 * 2**lv for lv in range(levels)) if c <= n_frames)


def sparse_hierarchy(
    embedding: Float[Array, "T 2"],
    graph: NeighbourGraph,
    levels: int = 4,
    c0: int = 10,
    *,
    key: Array | None = None,
    nearest: int = 8,
    links: bool = True,
) -> list[SparseLevel]:
    """FCM levels (sparse memberships) and their links on the sparse graph.

    **Arguments:** `embedding` ``(T, 2)``; `graph` the frames' neighbourhood graph;
    `levels` levels of c0·2^l centres; `key` seeding; `nearest` memberships kept per
    frame; `links` compute the links (else empty).

    **Returns:** a list of `SparseLevel`, coarse to fine.

    **Example:**

    ```python
    h = fx.navigation.sparse_hierarchy(es.embedding, es.graph, levels=5)
    frames = fx.navigation.sparse_route(es.graph, h[-1].center_frames[[0, 5, 9]])
    ```
    """
    Y = jax.numpy.asarray(embedding)
    Yn = np.asarray(Y, np.float64)
    key = jax.random.key(0) if key is None else key
    out = []
    for lv, c in enumerate(sparse_levels(c0, levels, Y.shape[0])):
        res = sparse_fuzzy_cmeans(Y, c, nearest=nearest, key=jax.random.fold_in(key, lv))
        centers = np.asarray(res.centers)
        cf = _nearest_frames(Yn, centers)
        if links:
            lk, br = sparse_links(graph, Yn, cf)
        else:
            lk = br = np.zeros((c, c), bool)
        out.append(SparseLevel(c, centers, cf, lk, br, res))
    return out


def sparse_route(graph: NeighbourGraph, key_frames: Sequence[int]) -> np.ndarray:
    """Frames along shortest graph paths through the key frames in order (no repeats at
    the joins)."""
    keys = [int(k) for k in key_frames]
    if len(keys) < 1:
        raise FxspaceError("key_frames must name at least one frame")
    frames = [np.asarray(keys[:1], np.int64)]
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        frames.append(sparse_shortest_path(graph, a, b)[1:])
    return np.concatenate(frames)
