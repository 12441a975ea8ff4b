"""A uniform-grid spatial index over 2-D points: the nearest centre of a level to a click.

Picking on the expression pad (seed paper §5: the animator clicks a centre at any level,
the finest included) must stay responsive with thousands of centres. The points are
bucketed into a grid of about one point per cell; a query visits the rings of cells
around the query's cell until the ring's inner distance exceeds the best distance found,
so it touches O(1) cells for a query inside the data's box and O(√c) in the worst case
(build O(c log c)).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float

from fxspace.errors import FxspaceError

__all__ = ["GridIndex"]


class GridIndex:
    """Nearest-neighbour queries over fixed 2-D ``points``.

    **Arguments:**

    - `points`: ``(c, 2)`` positions (e.g. a level's centre frames in the embedding).
    - `ids`: ``(c,)`` what a query returns for each point (default ``0 … c−1``).

    **Example:**

    ```python
    idx = GridIndex(h.embedding[h.levels[-1].center_frames])
    k = idx.nearest([0.1, -0.3])       # the centre nearest the click
    ```
    """

    def __init__(self, points: Float[np.ndarray, "c 2"], ids: np.ndarray | None = None):
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 1:
            raise FxspaceError(f"points must be a non-empty (c, 2) array, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise FxspaceError("points must be finite")
        self.points = p
        self.ids = np.arange(len(p)) if ids is None else np.asarray(ids)
        if len(self.ids) != len(p):
            raise FxspaceError(f"ids has {len(self.ids)} entries for {len(p)} points")
        lo, hi = p.min(0), p.max(0)
        n = max(1, int(np.ceil(np.sqrt(len(p)))))
        self.lo = lo
        self.cell = max(float(np.max(hi - lo)) / n, 1e-12)
        self.shape = np.maximum(np.ceil((hi - lo) / self.cell).astype(np.int64), 1)
        ij = self._cell_of(p)
        flat = ij[:, 0] * self.shape[1] + ij[:, 1]
        self._order = np.argsort(flat, kind="stable")
        n_cells = int(self.shape[0] * self.shape[1])
        self._starts = np.searchsorted(flat[self._order], np.arange(n_cells + 1))

    def _cell_of(self, q: np.ndarray) -> np.ndarray:
        ij = np.floor((q - self.lo) / self.cell).astype(np.int64)
        return np.clip(ij, 0, self.shape - 1)

    def _bucket(self, i: int, j: int) -> np.ndarray:
        f = i * self.shape[1] + j
        return self._order[self._starts[f] : self._starts[f + 1]]

    def nearest(self, q) -> int:
        """The id of the point nearest ``q`` (ties: the lower index)."""
        return int(self.ids[self.nearest_index(q)])

    def nearest_index(self, q) -> int:
        """Row of ``points`` nearest ``q``."""
        q = np.asarray(q, dtype=np.float64).reshape(2)
        ci, cj = self._cell_of(q[None])[0]
        best, best_d = -1, np.inf
        r = 0
        R = int(max(self.shape))
        while r <= R:
            # every point of ring r differs from q's (clipped) cell by r cells along one
            # axis, so it lies at least (r − 1) cells away
            if best >= 0 and (r - 1) * self.cell > best_d:
                break
            cand = []
            for i in range(ci - r, ci + r + 1):
                if not 0 <= i < self.shape[0]:
                    continue
                if abs(i - ci) == r:
                    js = range(cj - r, cj + r + 1)
                else:
                    js = (cj - r, cj + r)
                for j in js:
                    if 0 <= j < self.shape[1]:
                        b = self._bucket(i, j)
                        if len(b):
                            cand.append(b)
            if cand:
                idx = np.concatenate(cand)
                d = np.sqrt(np.sum((self.points[idx] - q) ** 2, axis=1))
                k = int(np.lexsort((idx, d))[0])
                if d[k] < best_d or (d[k] == best_d and idx[k] < best):
                    best, best_d = int(idx[k]), float(d[k])
            r += 1
        return best
