"""The FCM solver objects of a hierarchy's levels (optimistix style: the options sit on
the object, `fxspace.navigation.build_hierarchy(..., fcm=...)`): `FuzzyCMeans` (full
memberships, ~10³ frames) and `TruncatedFuzzyCMeans` (each frame's nearest centres, 10⁵
frames and more, a block of frames a task)."""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import numpy as np

from fxspace.cluster import fuzzy_cmeans, precompile_fcm_blocks
from fxspace.errors import FxspaceError

__all__ = ["FuzzyCMeans", "TruncatedFuzzyCMeans"]


@dataclasses.dataclass(frozen=True)
class FuzzyCMeans:
    """Each level's fuzzy c-means with full ``(T, c)`` memberships, run to its fixed point
    (`fxspace.cluster.fuzzy_cmeans`).

    **Fields:** `m`, `tol`, `max_steps`, `criterion` (the FCM); `warm_start` (start level
    l+1 from level l: its centres split and, with `restarts` ≥ 1, `restarts` runs keeping
    the coarse centres with k-means++-drawn new ones; the lowest objective wins; without
    it every level starts from 1 + `restarts` k-means++ seeds); `split` (include the
    split start); `first_level_seeds` (k-means++ seeds at the first level).
    """

    m: float = 2.0
    tol: float = 1e-4
    max_steps: int = 300
    criterion: Literal["max", "fro"] = "max"
    warm_start: bool = True
    restarts: int = 1
    split: bool = True
    first_level_seeds: int = 8

    def __post_init__(self):
        if not self.m > 1 or not self.tol > 0 or int(self.max_steps) < 1:
            raise FxspaceError("FCM: need m > 1, tol > 0, max_steps >= 1")
        if int(self.restarts) < 0:
            raise FxspaceError(f"restarts must be >= 0, got {self.restarts}")
        if not self.split and int(self.restarts) < 1:
            raise FxspaceError("split=False needs restarts >= 1 (the k-means++-extend starts)")

    def precompile(self, x, sizes) -> None:
        """Compile ahead what the runs for each centre count in ``sizes`` will need (a
        thread beside the first level; here nothing: the full solver compiles as it
        runs)."""

    def run(self, x, c: int, init_centers):
        """One FCM run from ``init_centers`` ``(c, d)``."""
        return fuzzy_cmeans(x, c, self.m, init_centers=init_centers, tol=self.tol,
                            max_steps=self.max_steps, criterion=self.criterion)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class TruncatedFuzzyCMeans(FuzzyCMeans):
    """Each level's fuzzy c-means keeping each frame's `nearest` centres (memory O(T·p):
    10⁵ frames and hundreds of centres), run to its fixed point (no centre moving more
    than `tol` × the data's spread); `max_steps` is only the cap, reported when hit.
    `rows_per_task` / `client`: each step a block of frames a task, here or as Dask tasks
    (the same numbers for the same `rows_per_task`); `accelerate` (only with them; None:
    on): SQUAREM cycles on the blocks (`fxspace.cluster.fuzzy_cmeans`), False: plain
    steps. Other fields as `FuzzyCMeans` (`criterion` is not used: the stop is the
    centres')."""

    nearest: int = 8
    max_steps: int = 2000
    restarts: int = 0
    first_level_seeds: int = 4
    chunk: int = 8192
    rows_per_task: int | None = None
    client: Any = dataclasses.field(default=None, compare=False, repr=False)
    accelerate: bool | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.accelerate is not None and self.rows_per_task is None and self.client is None:
            raise FxspaceError("accelerate applies to the block solver: set rows_per_task or "
                               "client too")  # fmt: skip

    def precompile(self, x, sizes) -> None:
        """With `rows_per_task` here (no client): the block kernels of each centre count
        in ``sizes`` compiled ahead (`fxspace.cluster._fcm_blocks.precompile`)."""
        if self.rows_per_task is None or self.client is not None or not len(sizes):
            return
        if x.dtype not in (np.float32, np.float64):  # the runs say what they make of it
            return
        n, d = x.shape
        precompile_fcm_blocks(n, d, x.dtype, sizes, self.m, self.nearest, self.chunk,
                              self.rows_per_task)  # fmt: skip

    def run(self, x, c: int, init_centers):
        """One FCM run; with `rows_per_task` or `client`, a block of points a task, here
        or on the Dask client (`fxspace.cluster.fuzzy_cmeans`: the same numbers either
        way for the same `rows_per_task`)."""
        blocks = {}
        if self.rows_per_task is not None or self.client is not None:
            blocks = {"rows_per_task": self.rows_per_task, "client": self.client,
                      "accelerate": self.accelerate}
        return fuzzy_cmeans(x, c, self.m, nearest=self.nearest, init_centers=init_centers,
                            tol=self.tol, max_steps=self.max_steps, chunk=self.chunk,
                            **blocks)  # fmt: skip
