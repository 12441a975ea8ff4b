"""One level of the hierarchy and the hierarchy itself, at every size (Kim & Jung §4).

A `Level` holds its centres, the frame showing each, its FCM record (`Level.fit`: full
memberships from `FuzzyCMeans` or truncated ones from `TruncatedFuzzyCMeans`, with
``.result`` and ``.stats``) and its links in one sparse form: ``(c, c)`` symmetric
``scipy.sparse.csr_array``\\ s (a small level's is just a small CSR), with the geodesic
length of each link beside them.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fxspace._validate import checked
from fxspace.cluster import FCMResult, SparseFCMResult
from fxspace.errors import FxspaceError
from fxspace.results import RESULTS, member_code, result_from_code

__all__ = [
    "Level",
    "Hierarchy",
    "level_sizes",
    "pair_csr",
    "link_pairs",
    "link_components",
    "link_graph_connected",
    "hierarchy_to_arrays",
    "hierarchy_from_arrays",
]


def pair_csr(i, j, vals, c: int):
    """Symmetric ``(c, c)`` ``csr_array`` (sorted indices, no diagonal) from unordered
    pairs i ≠ j and their values."""
    from scipy.sparse import csr_array

    i = np.asarray(i, np.int64).reshape(-1)
    j = np.asarray(j, np.int64).reshape(-1)
    vals = np.asarray(vals).reshape(-1)
    m = csr_array(
        (np.concatenate([vals, vals]), (np.concatenate([i, j]), np.concatenate([j, i]))),
        shape=(c, c),
    )
    m.sum_duplicates()
    m.sort_indices()
    return m


class Level(NamedTuple):
    """One level of the hierarchy, at any size.

    **Fields:**

    - `n_clusters`: c; `centers`: ``(c, 2)`` FCM centres; `center_frames`: ``(c,)`` the
      frame nearest each centre (how a centre is shown).
    - `fit`: the level's FCM record — an `fxspace.cluster.FCMResult` (full ``(T, c)``
      memberships) or a `fxspace.cluster.SparseFCMResult` (each frame's nearest centres),
      with ``.result`` (a `RESULTS` member: ``successful`` at the fixed point,
      ``max_steps_reached`` where the cap stopped it) and ``.stats``. The level where
      every frame is a centre has the trivial record (each frame its own centre, J = 0).
    - `links`, `bridges`: ``(c, c)`` symmetric ``csr_array`` of bool, no diagonal (None
      when not computed); bridges ⊂ links, added outside the paper's rule only on request.
    - `lengths`: ``(c, c)`` ``csr_array`` with the links' sparsity: the geodesic length of
      each link (route chains are weighed by it).
    - `radius`: the ρ of the links (nan when not computed).
    - `stats`: how the level was started: ``init`` (``"split"``, ``"kmeans++-extend"``,
      ``"kmeans++"`` or ``"frames"``), ``num_steps_split``, ``total_steps``.
    """

    n_clusters: int
    centers: np.ndarray
    center_frames: np.ndarray
    fit: Any
    links: Any = None
    bridges: Any = None
    lengths: Any = None
    radius: float = float("nan")
    stats: dict[str, Any] = {}

    @property
    def result(self):
        """The FCM's [`RESULTS`][fxspace.RESULTS] member."""
        return self.fit.result

    @property
    def converged(self) -> bool:
        """``result == RESULTS.successful``: the FCM reached its fixed point."""
        return bool(member_code(self.fit.result) == member_code(RESULTS.successful))

    @property
    def objective(self) -> float:
        return float(self.fit.objective)

    @property
    def num_steps(self) -> int:
        return int(self.fit.num_steps)

    @property
    def memberships(self) -> np.ndarray:
        """The FCM memberships: ``(T, c)``, or ``(T, p)`` on `fit.indices` when truncated."""
        return np.asarray(self.fit.memberships)

    @property
    def labels(self) -> np.ndarray:
        """(T,) each frame's hard cluster (largest membership)."""
        u = np.asarray(self.fit.memberships)
        k = np.argmax(u, axis=1)
        idx = getattr(self.fit, "indices", None)
        return k if idx is None else np.asarray(idx)[np.arange(len(k)), k].astype(np.int64)

    @property
    def init(self) -> str:
        return str(self.stats.get("init", ""))

    @property
    def num_steps_split(self) -> int:
        return int(self.stats.get("num_steps_split", -1))

    @property
    def total_steps(self) -> int:
        return int(self.stats.get("total_steps", -1))

    @property
    def n_links(self) -> int:
        return 0 if self.links is None else int(self.links.nnz // 2)

    @property
    def n_bridges(self) -> int:
        return 0 if self.bridges is None else int(self.bridges.nnz // 2)

    def _need_links(self):
        if self.links is None:
            raise FxspaceError("this level has no links; build the hierarchy with its paths")
        return self.links

    def neighbours(self, k: int) -> np.ndarray:
        """Centres linked to centre ``k`` (ascending)."""
        lk = self._need_links()
        return np.asarray(lk.indices[lk.indptr[k] : lk.indptr[k + 1]], np.int64)

    def linked(self, a: int, b: int) -> bool:
        """Whether centres ``a`` and ``b`` are linked."""
        row = self.neighbours(a)
        k = np.searchsorted(row, b)
        return bool(k < len(row) and row[k] == b)

    def link_length(self, a: int, b: int) -> float:
        """The geodesic length of link a—b (inf when not a link or not recorded)."""
        ln = self.lengths
        if ln is None:
            return np.inf
        row = ln.indices[ln.indptr[a] : ln.indptr[a + 1]]
        k = np.searchsorted(row, b)
        return float(ln.data[ln.indptr[a] + k]) if k < len(row) and row[k] == b else np.inf


class Hierarchy(NamedTuple):
    """All levels, coarse to fine, over one 2-D embedding."""

    levels: tuple[Level, ...]
    embedding: np.ndarray
    link_sweep: Any = None
    """The `LinkRadiusSweep` that chose ρ (``LinkRule(rho="experiment")``), else None."""

    @property
    def sizes(self) -> tuple[int, ...]:
        return tuple(lv.n_clusters for lv in self.levels)

    @property
    def converged(self) -> bool:
        """Whether every level's FCM reached its fixed point."""
        return all(lv.converged for lv in self.levels)


@checked
def level_sizes(n_frames: int, c0: int = 10) -> tuple[int, ...]:
    """c0, 2c0, 4c0, … while below ``n_frames``, then ``n_frames`` (the level showing every
    frame). The number of levels is ⌈log2(T / c0)⌉ + 1."""
    if int(c0) < 1:
        raise FxspaceError(f"c0 must be >= 1, got {c0}")
    if int(n_frames) < 1:
        raise FxspaceError(f"n_frames must be >= 1, got {n_frames}")
    sizes = []
    c = int(c0)
    while c < n_frames:
        sizes.append(c)
        c *= 2
    sizes.append(int(n_frames))
    return tuple(sizes)


def _components(links) -> np.ndarray:
    from scipy.sparse.csgraph import connected_components

    return connected_components(links, directed=False)[1]


@checked
def link_components(level: Level) -> np.ndarray:
    """The piece (connected group of the level's links) of each centre, ``(c,)`` int
    labels 0…: one label when every centre reaches every other through links."""
    return _components(level._need_links())


@checked
def link_graph_connected(level: Level) -> bool:
    """Whether the level's link graph is connected."""
    return len(np.unique(link_components(level))) == 1


def link_pairs(links) -> tuple[np.ndarray, np.ndarray]:
    """The linked pairs ``(i, j)`` with ``i < j`` of a level's links (a ``csr_array``;
    a dense ``(c, c)`` bool matrix is read too), without densifying."""
    if links is None:
        raise FxspaceError("links is None: this level has no links (build it with its paths)")
    if hasattr(links, "tocoo"):
        m = links.tocoo()
        keep = (m.row < m.col) & (np.asarray(m.data) != 0)
        return np.asarray(m.row[keep], np.int64), np.asarray(m.col[keep], np.int64)
    L = np.asarray(links)
    if L.ndim != 2 or L.shape[0] != L.shape[1] or L.dtype.kind not in "biu":
        raise FxspaceError(
            f"links must be a (c, c) csr_array or bool matrix, got {type(links).__name__} "
            f"of shape {L.shape}"
        )
    i, j = np.nonzero(np.triu(L, 1))
    return i.astype(np.int64), j.astype(np.int64)


# -- arrays (run caches, .npz) ---------------------------------------------------------


def _csr_arrays(out: dict, p: str, m) -> None:
    out[p + "indptr"] = np.asarray(m.indptr, np.int64)
    out[p + "indices"] = np.asarray(m.indices, np.int64)


def _csr_from(a, p: str, c: int, data=None):
    from scipy.sparse import csr_array

    ind = np.asarray(a[p + "indices"], np.int64)
    vals = np.ones(len(ind), bool) if data is None else np.asarray(data)
    return csr_array((vals, ind, np.asarray(a[p + "indptr"], np.int64)), shape=(c, c))


@checked
def hierarchy_to_arrays(h: Hierarchy) -> dict[str, np.ndarray]:
    """A flat ``{name: array}`` of a `Hierarchy` (for `fxspace.runs.cached_arrays` or an
    ``.npz``; no pickles): the embedding and, per level ``i``, ``l{i}_centers``,
    ``l{i}_center_frames``, the FCM record (memberships float32, their ``indices`` when
    truncated, objective, steps, result code, stats), the links / bridges in CSR form
    with the links' lengths, ρ and how the level started. `hierarchy_from_arrays`
    inverts it."""
    out: dict[str, np.ndarray] = {
        "embedding": np.asarray(h.embedding), "n_levels": np.asarray(len(h.levels)),
    }  # fmt: skip
    for i, lv in enumerate(h.levels):
        p = f"l{i}_"
        f = lv.fit
        out[p + "centers"] = np.asarray(lv.centers)
        out[p + "center_frames"] = np.asarray(lv.center_frames, np.int64)
        out[p + "memberships"] = np.asarray(f.memberships, np.float32)
        if getattr(f, "indices", None) is not None:
            out[p + "fit_indices"] = np.asarray(f.indices, np.int32)
        out[p + "objective"] = np.asarray(float(f.objective))
        out[p + "num_steps"] = np.asarray(int(f.num_steps))
        out[p + "result"] = np.asarray(member_code(f.result))
        for k, v in dict(f.stats).items():
            out[p + "fitstat_" + k] = np.asarray(v)
        out[p + "radius"] = np.asarray(float(lv.radius))
        out[p + "init"] = np.asarray(lv.init)
        for k in ("num_steps_split", "total_steps"):
            out[p + k] = np.asarray(int(lv.stats.get(k, -1)))
        if lv.links is not None:
            _csr_arrays(out, p + "links_", lv.links)
            _csr_arrays(out, p + "bridges_", lv.bridges)
            ln = lv.lengths
            out[p + "lengths"] = (np.asarray(ln.data, np.float64) if ln is not None
                                  else np.full(lv.links.nnz, np.inf))  # fmt: skip
    if h.link_sweep is not None:
        for k, v in h.link_sweep._asdict().items():
            out["link_sweep_" + k] = np.asarray(v)
    return out


def _fit_from(a, p: str, centers):
    stats = {k.removeprefix(p + "fitstat_"): np.asarray(a[k]) for k in a
             if k.startswith(p + "fitstat_")}  # fmt: skip
    res = result_from_code(np.asarray(a[p + "result"]).item())
    u = np.asarray(a[p + "memberships"])
    obj, steps = np.asarray(a[p + "objective"]), np.asarray(a[p + "num_steps"])
    if p + "fit_indices" in a:
        return SparseFCMResult(centers, np.asarray(a[p + "fit_indices"]), u, obj, steps, res,
                               stats)  # fmt: skip
    return FCMResult(centers, u, obj, steps, res, stats)


class LinkRadiusSweep(NamedTuple):
    """The link radius experiment of Kim & Jung §4.2 (`link_radius_sweep`).

    **Fields:** `scales` ``(S,)`` (ρ = scale × the level's median centre spacing);
    `levels` ``(L,)`` the swept level indices and `centres` their sizes; per level and
    scale ``(L, S)``: `radii` (ρ), `links` (pairs linked), `components` (groups of
    centres the links join) and `coverage` (the fraction of centre pairs a route can
    join through links: 1 when the level is connected).
    """

    scales: np.ndarray
    levels: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    links: np.ndarray
    components: np.ndarray
    coverage: np.ndarray


@checked
def hierarchy_from_arrays(a: dict[str, np.ndarray]) -> Hierarchy:
    """The `Hierarchy` stored by `hierarchy_to_arrays`."""
    if not (hasattr(a, "__getitem__") and hasattr(a, "__contains__")) or isinstance(a, str):
        raise FxspaceError(
            f"a must be the arrays of hierarchy_to_arrays (a dict or an NpzFile), got "
            f"{type(a).__name__}"
        )
    if hasattr(a, "files"):  # an NpzFile: read each array once
        a = {k: a[k] for k in a.files}
    try:
        levels = []
        for i in range(int(a["n_levels"])):
            p = f"l{i}_"
            cf = np.asarray(a[p + "center_frames"], np.int64)
            c = len(cf)
            centers = np.asarray(a[p + "centers"])
            links = bridges = lengths = None
            if p + "links_indptr" in a:
                links = _csr_from(a, p + "links_", c)
                bridges = _csr_from(a, p + "bridges_", c)
                lengths = _csr_from(a, p + "links_", c, a[p + "lengths"])
            levels.append(Level(
                c, centers, cf, _fit_from(a, p, centers), links, bridges, lengths,
                float(np.asarray(a[p + "radius"])),
                {"init": str(a[p + "init"]),
                 **{k: int(np.asarray(a[p + k])) for k in ("num_steps_split", "total_steps")}},
            ))  # fmt: skip
        sweep = None
        if "link_sweep_scales" in a:
            sweep = LinkRadiusSweep(*(np.asarray(a["link_sweep_" + f])
                                      for f in LinkRadiusSweep._fields))  # fmt: skip
        return Hierarchy(tuple(levels), np.asarray(a["embedding"]), sweep)
    except KeyError as e:
        raise FxspaceError(
            f"not a stored hierarchy: {e} missing (a cache from before issue 45: delete the "
            "run's cache/hierarchy to rebuild it)"
        ) from None


SparseLevel = Level
"""Deprecated alias: one `Level` type serves every size since issue 45."""


def is_sparse(h: Hierarchy) -> bool:
    """Whether the hierarchy's FCM levels keep truncated memberships (built with
    `TruncatedFuzzyCMeans`). Kept for old callers: every function takes either kind."""
    if not isinstance(h, Hierarchy):
        raise FxspaceError(f"h must be a Hierarchy (build_hierarchy), got {type(h).__name__}")
    return any(getattr(lv.fit, "indices", None) is not None and lv.init != "frames"
               for lv in h.levels)  # fmt: skip
