"""Max-min landmarks in rounds: ``batch`` landmarks chosen at once, their shortest-path
rows computed in parallel (in this process or as Dask tasks).

Exact max-min (`farthest_point_landmarks` without ``batch``) needs each landmark's row
before the next pick. In rounds, the first ``batch`` landmarks are picked that way; then
each round picks ``batch`` landmarks by max-min on an estimate of the distance to the
landmarks picked earlier in the same round, whose rows are not known yet: the lower
bound (the triangle inequality, as in ALT search; Goldberg & Harrelson 2005)

    d(b, a) ≥ max_{l ∈ K} |d(l, b) − d(l, a)|

over ``K``, the first ``min(L, 32)`` landmarks (their rows are known from the first
rounds on). A round's first pick is exact max-min; ``batch = 1`` is the sequential
result. Then the round's ``batch`` rows run at once: one Dijkstra task each on a Dask
client (the graph's CSR scattered to every worker once), or here. Every row is the same
scipy Dijkstra of the same CSR wherever it runs, and every pick is made here, so a
cluster gives the landmarks and rows of one process, bit for bit.

What travels: the CSR once per worker (``nnz`` float64 + int32, ``T + 1`` int32: 0.12 GB
at 10⁶ frames and ~10 neighbours); per round, ``batch`` frame numbers out and ``batch``
rows back (``batch × T`` floats: 4 MB a row at 10⁶ float32 frames).
"""

from __future__ import annotations

import numpy as np

from fxspace._progress import progress
from fxspace.errors import FxspaceError

__all__: list[str] = []

_BOUND_ROWS = 32  # landmarks whose rows make the lower bound (cost O(32) a frame estimated)
_TOP = 4096  # frames ranked by their distance to the landmarks first (all where a scan needs)
_SCAN = 512  # frames estimated at once in a round's pick
_CSRS: dict[tuple, tuple] = {}  # the rebuilt CSR, per process (worker)


def _dijkstra_row(data, indices, indptr, directed: bool, dtype: str, source: int) -> np.ndarray:
    """One shortest-path row ``(T,)`` from ``source`` on the CSR ``(data, indices,
    indptr)`` (scipy's Dijkstra), as ``dtype``: the same code here and on a worker."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    key = (id(data), id(indices), id(indptr))
    hit = _CSRS.get(key)
    if hit is None or hit[0] is not data:
        _CSRS.clear()
        n = len(indptr) - 1
        hit = _CSRS[key] = (data, csr_matrix((data, indices, indptr), shape=(n, n)))
    row = dijkstra(hit[1], directed=directed, indices=np.array([int(source)]))
    return np.atleast_2d(row)[0].astype(dtype)


class Rows:
    """Shortest-path rows of many sources, here (split between worker processes on a
    large graph: ``workers``, `fxspace.expression._row_workers`) or as Dask tasks (the CSR
    sent once)."""

    def __init__(self, csr, directed: bool, dtype, client, workers=None):
        self.client = client
        self.workers = workers if client is None else None
        self.shared = (csr.data, csr.indices, csr.indptr)
        self.args = (bool(directed), np.dtype(dtype).str)
        if client is not None:
            self.shared = tuple(client.scatter(a, broadcast=True, hash=False)
                                for a in self.shared)  # fmt: skip

    def __call__(self, sources) -> list[np.ndarray]:
        if self.workers is not None and len(sources) > 1:
            return list(self.workers.rows(sources).astype(self.args[1]))
        if self.client is None:
            return [_dijkstra_row(*self.shared, *self.args, s) for s in sources]
        futures = [self.client.submit(_dijkstra_row, *self.shared, *self.args, int(s),
                                      pure=False) for s in sources]  # fmt: skip
        return self.client.gather(futures)


def lower_bound(rows: np.ndarray, b: int) -> np.ndarray:
    """``max_l |rows[l, b] − rows[l, :]|`` ``(T,)``: a lower bound of the geodesic from
    frame ``b`` to every frame, from the rows ``(K, T)`` of K known sources."""
    return np.max(np.abs(rows[:, b : b + 1] - rows), axis=0)


def _pick(est: np.ndarray, taken: set[int], n: int) -> int:
    nxt = int(np.argmax(est))
    if est[nxt] == 0:  # fewer distinct frames than landmarks asked for
        nxt = next(i for i in range(n) if i not in taken)
    return nxt


def _ranked(mind: np.ndarray, top: int) -> np.ndarray:
    """Frames by ``mind``, largest first, ties by index (`np.argmax`'s order): at least
    the ``top`` first and every frame tied with the last of them; all where ``top`` ≥ T."""
    if top < len(mind):
        lim = mind[np.argpartition(-mind, top - 1)[top - 1]]
        some = np.flatnonzero(mind >= lim)
        return some[np.lexsort((some, -mind[some]))]
    return np.lexsort((np.arange(len(mind)), -mind))


def _scan(order: np.ndarray, mind, bound, new: list[int]) -> tuple[float, int, bool]:
    """``(best, frame, settled)``: the largest ``min(mind, lower bounds from new)`` over
    ``order`` (the first frame among ties), scanned `_SCAN` frames at a time in ``order``
    until the next ``mind`` is below the best found (no later frame can beat it:
    ``settled``); unsettled where ``order`` ran out first."""
    best, arg = -np.inf, -1
    for s in range(0, len(order), _SCAN):
        cand = order[s : s + _SCAN]
        if mind[cand[0]] < best:
            return best, arg, True
        est = mind[cand]
        for b in new:
            est = np.minimum(est, np.max(np.abs(bound[:, b : b + 1] - bound[:, cand]), axis=0))
        m = est.max()
        if m >= best:
            i = int(cand[est == m].min())
            arg = i if m > best else min(arg, i)
            best = m
    return best, arg, len(order) == len(mind)


def round_picks(mind: np.ndarray, bound: np.ndarray, taken: set[int], count: int,
                n: int) -> list[int]:  # fmt: skip
    """A round's ``count`` picks: each the frame of largest ``mind`` (the distance to the
    landmarks whose rows are known) lowered by `lower_bound` from the round's earlier
    picks — exactly `np.argmax` of that estimate over all frames, but found lazily: the
    frames in decreasing ``mind`` (`_ranked`), each estimated only until the next
    ``mind`` is below the best estimate found (an estimate never exceeds ``mind``). On
    10⁵ frames the round's T-wide bounds were 0.7 s of the 3.0 s landmark pass."""
    new: list[int] = []
    order = _ranked(mind, _TOP)
    for _ in range(count):
        best, arg, settled = _scan(order, mind, bound, new)
        if not settled:  # the top frames ran out before the stop: scan them all
            order = _ranked(mind, len(mind))
            best, arg, settled = _scan(order, mind, bound, new)
        if best == 0:  # fewer distinct frames than landmarks asked for
            arg = next(i for i in range(n) if i not in taken and i not in new)
        new.append(arg)
    return new


def rounds(first: int, num: int, batch: int, n: int, run) -> tuple[list[int], list]:
    """Landmarks ``[first, …]`` (``num``) and their rows, ``batch`` a round (module
    docstring); ``run(sources)`` returns the rows of a list of sources."""
    bar = iter(progress(range(num), "landmark rows", total=num))
    lm, rows = [first], run([first])
    next(bar, None)
    mind = rows[0].copy()
    while len(lm) < min(num, batch):  # the first batch: exact max-min
        lm.append(_pick(mind, set(lm), n))
        rows += run(lm[-1:])
        next(bar, None)
        mind = np.minimum(mind, rows[-1])
    bound = None
    while len(lm) < num:
        if bound is None or len(bound) < min(len(rows), _BOUND_ROWS):  # fixed once full
            bound = np.stack(rows[:_BOUND_ROWS])
        new = round_picks(mind, bound, set(lm), min(batch, num - len(lm)), n)
        lm += new
        rows += run(new)
        for r in rows[-len(new) :]:
            mind = np.minimum(mind, r)
            next(bar, None)
    for _ in bar:  # closes the progress line
        pass
    return lm, rows


def check_batch(batch, client, method: str, n: int) -> int | None:
    """``batch`` as an int (``None``: sequential), or an `FxspaceError` naming the fix."""
    if batch is None:
        if client is not None:
            raise FxspaceError(
                "client runs the landmark rows in rounds: pass batch too (landmarks a "
                "round, e.g. batch=16, one Dijkstra task each)"
            )
        return None
    if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
        raise FxspaceError(f"batch must be an int >= 1 (landmarks a round), got {batch!r}")
    if client is not None and method == "relax":
        raise FxspaceError(
            "method='relax' runs here (jit Bellman-Ford); on a Dask client the rows are "
            "scipy's Dijkstra: pass method='dijkstra' or 'auto', or client=None"
        )
    return min(int(batch), n)
