"""The k-NN graph of marker frames a block at a time, in this process or on a Dask cluster.

`neighbourhood_graph` takes the whole ``(T, P)`` feature matrix (P = M(M−1)/2 marker
distances: 1770 for 60 markers, 7 GB at 10⁶ frames). Here the features are never held
whole: each block of frames makes its own from the positions, and each stage is a task
per block, run in this process (``client=None``) or as Dask tasks on any
``dask.distributed.Client`` (a `LocalCluster` or a real scheduler):

1. **features** (a task per block): the block's features, written into one
   memory-mapped ``.npy`` on disk (``T × P``);
2. **axes** (here): principal axes of the features of ≤ 20 000 frames drawn with a
   fixed seed — the candidate search's low-dimensional space — and (a task per block)
   every frame's projection ``(T, d)``;
3. **neighbours** (a task per block): each frame's ``C`` nearest in the projection
   (a k-d tree over every frame's projection, built once per worker), then the exact
   feature distances to them (the candidates' rows read from the ``.npy``) and the
   ``k`` nearest kept; the block's frames go in the tree's leaf order (frames in a row
   are near and share candidates: a faster search, fewer pages read) and come back in
   frame order;
4. **pack** (here): the symmetric `NeighbourGraph`.

Every block runs the same code wherever it runs, so a cluster gives the graph of one
process, bit for bit. What travels: the positions once to each worker (``T × M × 3``
floats), the projection once (``T × d``), per block the indices and lengths back
(``T_b × k``); the features go through the ``.npy``, which every worker must reach (a
local cluster shares this machine's disk; a real one needs a shared folder, as the
sweep's run folders do). Memory: the positions, the projection and a few blocks.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from fxspace._progress import progress
from fxspace._validate import check_int, check_scalar
from fxspace.errors import FxspaceError
from fxspace.expression._features import PAIR_WEIGHT
from fxspace.expression._sparse import NeighbourGraph, _pack, _principal_axes

__all__ = ["neighbourhood_graph_blocks"]

_AXES_SAMPLE = 20000
_ROWS = 256  # frames whose candidates are read at once
_FEAT_ROWS = 128  # frames whose features are formed at once (in cache)
_SEARCH_EPS = 0.5  # the candidate search's k-d tree tolerance (measured on 10⁵ frames of
# the synthetic face: the search 4.3 → 1.9 s, one thread; recall unchanged. AnimFace
# resampled to 6 000 frames: recall 0.987 → 0.985 and the takes stay apart; at 1.0,
# 0.982 and a false edge joined two takes)
_SUB = 8  # frames whose candidate differences are formed at once (in cache)
_TREES: dict[tuple, Any] = {}  # one k-d tree per projection, per process (worker)
_TREE_LOCK = threading.Lock()
_HERE = 2  # blocks at once without a client (threads)


def _block_features(positions: np.ndarray, rows: np.ndarray, block: int, out=None) -> np.ndarray:
    """`fxspace.distance_features` of ``positions[rows]`` in numpy, in the positions'
    float type (float64 for integer positions), ``block`` rows read at a time and
    ``_FEAT_ROWS`` formed at once (in cache), coordinate by coordinate
    (``√(dx² + dy² + dz²)``, summed in that order): the same numbers in every process,
    whatever its JAX settings and the block sizes. Written into ``out`` when given."""
    M = positions.shape[1]
    iu, ju = np.triu_indices(M, 1)
    dtype = positions.dtype if positions.dtype.kind == "f" else np.dtype(np.float64)
    out = np.empty((len(rows), len(iu)), dtype) if out is None else out
    tmp = np.empty((2, min(_FEAT_ROWS, len(rows)), len(iu)), dtype)
    for s in range(0, len(rows), block):
        x = np.asarray(positions[rows[s : s + block]], dtype)
        for r in range(0, len(x), _FEAT_ROWS):
            acc = out[s + r : s + min(r + _FEAT_ROWS, len(x))]
            d, dj = tmp[0, : len(acc)], tmp[1, : len(acc)]
            for c in range(3):
                xc = np.ascontiguousarray(x[r : r + _FEAT_ROWS, :, c])
                dst = acc if c == 0 else d
                np.take(xc, iu, axis=1, out=dst, mode="clip")  # clip: unbuffered
                np.take(xc, ju, axis=1, out=dj, mode="clip")
                dst -= dj
                dst *= dst
                if c:
                    acc += d
            np.sqrt(acc, out=acc)
            acc *= dtype.type(PAIR_WEIGHT)
    return out


def _features_to_disk(positions, start: int, stop: int, path: str, block: int) -> None:
    """Write the features of frames [start, stop) into rows [start, stop) of the ``.npy``
    at ``path`` (formed in place, in the mapped file)."""
    out = np.load(path, mmap_mode="r+")
    _block_features(positions, np.arange(start, stop), block, out=out[start:stop])
    out.flush()
    del out


def _project(path: str, start: int, stop: int, mean, axes) -> np.ndarray:
    F = np.load(path, mmap_mode="r")[start:stop]
    return ((F - mean) @ axes).astype(axes.dtype)


def _tree(Z: np.ndarray):
    """``(tree, rank)``: the k-d tree over Z (built once per process) and each frame's
    place in the tree's leaf order (frames close in Z are close in that order)."""
    from scipy.spatial import cKDTree

    key = (id(Z), Z.shape)
    with _TREE_LOCK:  # blocks may run in threads: one tree
        hit = _TREES.get(key)
        if hit is None or hit[0] is not Z:
            _TREES.clear()
            tree = cKDTree(Z)
            rank = np.empty(len(Z), np.int64)
            rank[tree.indices] = np.arange(len(Z))
            hit = _TREES[key] = (Z, tree, rank)
    return hit[1], hit[2]


def _distances(feats: np.ndarray, F: np.ndarray, cand: np.ndarray, out: np.ndarray) -> None:
    """``out[i, j] = ‖feats[cand[i, j]] − F[i]‖``, each pair's squares summed alone over a
    contiguous row (numpy's pairwise sum: the same numbers whatever the batch), ``_SUB``
    frames at a time in one reused buffer (in cache; no allocation per batch)."""
    buf = np.empty((min(_SUB, len(cand)), cand.shape[1], feats.shape[1]), feats.dtype)
    acc = np.empty(buf.shape[:2], feats.dtype)
    for r in range(0, len(cand), _SUB):
        b, a = buf[: len(cand[r : r + _SUB])], acc[: len(cand[r : r + _SUB])]
        np.take(feats, cand[r : r + _SUB], axis=0, out=b, mode="clip")  # clip: unbuffered
        np.subtract(b, F[r : r + _SUB, None, :], out=b)
        np.multiply(b, b, out=b)
        np.add.reduce(b, axis=2, out=a)
        np.sqrt(a, out=out[r : r + len(a)])


def _neighbours(path: str, Z, start: int, stop: int, num: int, k: int, workers: int = 1,
                eps: float = 0.0):
    """``(cand, dist)`` ``(stop − start, k)``: each frame's k nearest (exact features,
    read from the ``.npy`` at ``path``, among its ``num`` nearest in the projection Z;
    itself excluded; ties in the order of the projection's nearest). Distances in the
    features' float type, each ``(frame, candidate)`` pair summed alone (the same numbers
    whatever the blocks). The frames go in the tree's leaf order (neighbours in a row
    share candidates: a faster search and fewer rows read) and come back in frame order;
    ``workers`` threads search the tree (each frame's search alone: the same answer);
    ``eps``: the tree's approximate search (each candidate within ``1 + eps`` of the
    projection's true ``num``-th nearest)."""
    tree, rank = _tree(Z)
    f = start + np.argsort(rank[start:stop], kind="stable")
    _, ii = tree.query(Z[f], k=min(num + 1, len(Z)), eps=eps, workers=workers)
    own = ii == f[:, None]
    own[:, -1] |= ~own.any(axis=1)
    cand = ii[~own].reshape(stop - start, -1).astype(np.int64)
    dtype = np.load(path, mmap_mode="r").dtype
    out_c = np.empty((stop - start, k), np.int64)
    out_d = np.empty((stop - start, k), dtype)
    d = np.empty(cand.shape, dtype)
    for s in range(0, stop - start, _ROWS):
        # mapped afresh per chunk: the pages read leave this process's resident set with
        # the chunk (they stay in the page cache), so memory is a few chunks, not the file
        feats = np.load(path, mmap_mode="r")
        _distances(feats, feats[f[s : s + _ROWS]], cand[s : s + _ROWS], d[s : s + _ROWS])
        del feats
    order = np.argsort(d, axis=1, kind="stable")[:, :k]
    out_c[f - start] = np.take_along_axis(cand, order, axis=1)
    out_d[f - start] = np.take_along_axis(d, order, axis=1)
    return out_c, out_d


def _spans(T: int, rows: int, parts: int = 1) -> list[tuple[int, int]]:
    """Consecutive spans of at most ``rows`` frames, their number a multiple of ``parts``
    (the threads that run them: none idle at the end), of equal sizes ±1."""
    n = -(-T // max(1, rows))
    n = min(T, -(-n // parts) * parts) if T else 0
    edges = np.linspace(0, T, n + 1).round().astype(np.int64) if n else np.zeros(1, np.int64)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _map(client, fn, shared: tuple, items: list[tuple], desc: str) -> list:
    """``fn(*shared, *item)`` for each item: here (`_HERE` at once, in threads: numpy and
    the k-d tree release the GIL), or as Dask tasks (``shared`` sent to every worker
    once); a progress line ``desc`` counts the items done."""
    if client is None:
        if _HERE < 2 or len(items) < 2:
            return [fn(*shared, *it) for it in progress(items, desc, total=len(items))]
        with ThreadPoolExecutor(_HERE) as pool:
            done = pool.map(lambda it: fn(*shared, *it), items)
            return list(progress(done, desc, total=len(items)))
    # hash=False: each call its own keys (a content key shared with the call before
    # could be released under the tasks that need it)
    sent = [client.scatter(v, broadcast=True, hash=False) if isinstance(v, np.ndarray) else v
            for v in shared]  # fmt: skip
    futures = [client.submit(fn, *sent, *it, pure=False) for it in items]
    for f in progress(futures, desc, total=len(futures)):  # done in order
        f.result()
    return client.gather(futures)


def neighbourhood_graph_blocks(
    positions, k: int = 10, *, reduce_dim: int = 8, candidates: int | None = None,
    rows_per_task: int = 20000, block: int = 2048, store=None, client=None,
    search_eps: float = _SEARCH_EPS,
) -> NeighbourGraph:  # fmt: skip
    """The symmetric k-NN graph of the frames' marker-distance features, a block of
    frames at a time (module docstring), never the whole feature matrix.

    **Arguments:**

    - `positions`: ``(T, M, 3)`` marker frames (no NaN), a numpy array or memory-mapped.
    - `k`: neighbours chosen by each frame (degrees are ``≥ k`` after symmetrising).
    - `reduce_dim`, `candidates`: the candidate search's principal axes and candidates per
      frame (default ``max(3k, k + 16)``), as in `fxspace.neighbourhood_graph`.
    - `rows_per_task`: frames per task; `block`: frames per compiled feature call.
    - `store`: where the ``(T, P)`` features are written (a ``.npy``, memory-mapped; a
      path every worker can reach, not existing yet); default a temporary file,
      deleted at the end.
    - `client`: a ``dask.distributed.Client`` to run the tasks on (``None``: here).
    - `search_eps`: the candidate search's tolerance in the projection (the k-d tree's
      ``eps``: each of a frame's candidates within ``1 + search_eps`` of its true
      ``candidates``-th nearest there; 0: exact there). The k kept are still chosen by
      exact feature distances among the candidates; the default, 0.5, halves the search
      and keeps the exact neighbours on the real captures as 0 does (`knn_quality` on
      AnimFace resampled: recall 1.0 at 10⁵ frames, 0.985 against 0.987 at 6 000).

    **Returns:** a `NeighbourGraph`; the same with or without a client.

    **Example:** ``g = fx.expression.neighbourhood_graph_blocks(positions, k=10)``
    """
    X = positions if isinstance(positions, np.memmap) else np.asarray(positions)
    if X.ndim != 3 or X.shape[-1] != 3 or X.shape[1] < 2:
        raise FxspaceError(f"positions must be (frames, markers >= 2, 3), got shape {X.shape}")
    T = X.shape[0]
    k = check_int(k, "k", low=1, high=T - 1)
    num = min(T - 1, candidates or max(3 * k, k + 16))
    if num < k:
        raise FxspaceError(f"candidates must be >= k = {k}, got {candidates}")
    rows_per_task = check_int(rows_per_task, "rows_per_task", low=1)
    block = check_int(block, "block", low=1)
    search_eps = check_scalar(search_eps, "search_eps", low=0.0)
    if not all(np.isfinite(X[s:e]).all() for s, e in _spans(T, rows_per_task)):
        raise FxspaceError("positions contain NaN/inf: clean the frames first (clean_frames)")
    dtype = X.dtype if X.dtype.kind == "f" else np.dtype(np.float64)
    spans = _spans(T, rows_per_task, _HERE if client is None else 1)
    with contextlib.ExitStack() as stack:
        if store is None:
            store = Path(stack.enter_context(tempfile.TemporaryDirectory())) / "features.npy"
        elif os.path.lexists(store):
            raise FxspaceError(
                f"store={str(store)!r} already exists (a file, folder or link); the features "
                "are never written over anything: remove it or give another path"
            )
        path = str(store)
        P = X.shape[1] * (X.shape[1] - 1) // 2
        np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=(T, P)).flush()
        _map(client, _features_to_disk, (X,), [(*sp, path, block) for sp in spans],
             "k-NN graph: features")  # fmt: skip
        rng = np.random.default_rng(0)
        sample = np.sort(rng.choice(T, min(T, _AXES_SAMPLE), replace=False))
        S = np.load(path, mmap_mode="r")[sample]
        mean = S.mean(axis=0)
        axes = _principal_axes(S, min(int(reduce_dim), P))
        del S
        Z = np.concatenate(_map(client, _project, (path,), [(*sp, mean, axes) for sp in spans],
                                "k-NN graph: projection"))  # fmt: skip
        threads = -1 if client is None else 1  # here: every core searches the tree
        got = _map(client, _neighbours, (path, Z),
                   [(*sp, num, k, threads, search_eps) for sp in spans],
                   "k-NN graph: neighbours")  # fmt: skip
    cand = np.concatenate([c for c, _ in got])
    dist = np.concatenate([d for _, d in got])
    rows = np.repeat(np.arange(T, dtype=np.int32), k)
    return _pack(rows, cand.reshape(-1).astype(np.int32), dist.reshape(-1), T, dist.dtype)
