"""One interface for dense and sparse hierarchies (Kim & Jung §3.4–3.6 at any scale).

A hierarchy comes in two implementations, chosen by what the data holds:

- **dense** — the frame graph's `Geodesics` (``T × T`` distances and next hops, about
  2 400 frames): `Level` objects with ``(c, c)`` link matrices (`fxspace.navigation
  ._hierarchy`, `._routes`);
- **sparse** — the frames' `fxspace.expression.NeighbourGraph` (k-NN, 10⁵ frames):
  `SparseLevel` objects with links as ``csr_array``\\ s and routes found by Dijkstra on
  the graph, no ``T × T`` or ``c × c`` matrix anywhere (`._scale`, `._scale_routes`).

Each public function here takes the hierarchy and the frames' *paths* (``Geodesics`` or a
``NeighbourGraph``) and runs the implementation they belong to; a dense hierarchy with a
graph (or the reverse) is refused naming the fix. Studio, pipelines and users call only
these names.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.expression import NeighbourGraph
from fxspace.navigation import _hierarchy as _dense_h
from fxspace.navigation import _links as _dense_links
from fxspace.navigation import _routes as _dense
from fxspace.navigation import _scale as _sparse_h
from fxspace.navigation import _scale_routes as _sparse
from fxspace.navigation._hierarchy import Hierarchy
from fxspace.navigation._routes import NavigationError, Route
from fxspace.navigation._scale import SparseLevel

__all__ = [
    "build_hierarchy",
    "hierarchy_to_arrays",
    "hierarchy_from_arrays",
    "center_links",
    "frame_path",
    "make_route",
    "bridge_keys",
    "path_candidates",
    "refine_route",
    "navigate",
    "is_sparse",
]


def is_sparse(h: Hierarchy) -> bool:
    """Whether the `Hierarchy` ``h`` is sparse (its levels are `SparseLevel`: built on a
    `NeighbourGraph`) rather than dense (`Level`: built on geodesics)."""
    if not isinstance(h, Hierarchy):
        raise FxspaceError(f"h must be a Hierarchy (build_hierarchy), got {type(h).__name__}")
    return _is_sparse(h)


def _is_sparse(h: Any) -> bool:
    return isinstance(h, Hierarchy) and bool(h.levels) and isinstance(h.levels[0], SparseLevel)


def _sparse_paths(h: Any, paths: Any) -> bool:
    """Which implementation ``(h, paths)`` belong to; a mixed pair is refused."""
    if not isinstance(h, Hierarchy):
        raise NavigationError(
            f"h must be a Hierarchy (build_hierarchy), got {type(h).__name__}; a list of "
            "levels is wrapped as Hierarchy(tuple(levels), embedding)"
        )
    sparse = _is_sparse(h)
    if sparse != isinstance(paths, NeighbourGraph):
        have = "sparse (SparseLevel)" if sparse else "dense (Level)"
        need = ("the frames' neighbourhood graph (NeighbourGraph)" if sparse
                else "the frame graph's Geodesics")  # fmt: skip
        raise NavigationError(
            f"the hierarchy is {have}: pass {need} as its paths, got {type(paths).__name__}"
        )
    return sparse


def build_hierarchy(
    embedding,
    geodesics=None,
    *,
    c0: int = 10,
    key=None,
    m: float | None = None,
    tol: float | None = None,
    max_steps: int | None = None,
    warm_start: bool | None = None,
    restarts: int | None = None,
    split: bool | None = None,
    first_level_seeds: int | None = None,
    rho_scale: float | Literal["experiment"] | None = None,
    max_link_centres: int | None = None,
    link_sweep_max_centres: int | None = None,
    criterion: Literal["max", "fro"] | None = None,
    bridges: bool | None = None,
    levels: int | None = None,
    nearest: int | None = None,
    links: bool | None = None,
    finest: bool | None = None,
) -> Hierarchy:
    """Fuzzy c-means levels c0·2^l over the expression-space ``embedding`` (Kim & Jung
    §3.4), with their links — dense or sparse by what ``geodesics`` is.

    **Arguments:**

    - `embedding`: ``(T, 2)`` MDS coordinates.
    - `geodesics`: the frame graph's ``Geodesics`` (or None: no links) → a **dense**
      hierarchy: every level to c = T, full memberships, ``(c, c)`` links. Options
      `m`, `tol`, `max_steps`, `criterion` (FCM), `warm_start`, `restarts`, `split`,
      `first_level_seeds` (how each level starts), `rho_scale`, `max_link_centres`,
      `link_sweep_max_centres`, `bridges` (links: by default the paper's rule with ρ
      chosen by its experiment and no bridges; True: bridges join the pieces a level
      is left in); see the dense builder's defaults.
      A `fxspace.expression.NeighbourGraph` → a **sparse** hierarchy: `levels` FCM levels
      (default 4) with `nearest` memberships per frame (default 8), `links` (default True)
      and, with `finest`, the level where every frame is a centre.
    - `c0`: centres at the coarsest level; `key`: PRNG key of the k-means++ draws.

    An option of the other implementation is refused, naming it.

    **Returns:** a `Hierarchy` (its levels `Level` or `SparseLevel`); routes are made on
    it with `make_route`, `bridge_keys`, `refine_route`, `navigate`.

    **Example:**

    ```python
    h = fx.build_hierarchy(space.embedding, space.geodesics, c0=10)          # dense
    hs = fx.build_hierarchy(es.embedding, es.graph, levels=5, finest=True)   # sparse
    ```
    """
    dense_opts = dict(m=m, tol=tol, max_steps=max_steps, warm_start=warm_start,
                      restarts=restarts, split=split, first_level_seeds=first_level_seeds,
                      rho_scale=rho_scale, max_link_centres=max_link_centres,
                      link_sweep_max_centres=link_sweep_max_centres, criterion=criterion,
                      bridges=bridges)  # fmt: skip
    sparse_opts = dict(levels=levels, nearest=nearest, links=links, finest=finest)
    if isinstance(geodesics, NeighbourGraph):
        given = sorted(k for k, v in dense_opts.items() if v is not None)
        if given:
            raise FxspaceError(
                f"{', '.join(given)}: options of a dense hierarchy (geodesics); with a "
                "NeighbourGraph the options are levels, nearest, links, finest, c0, key"
            )
        kw = {k: v for k, v in sparse_opts.items() if v is not None}
        lv = _sparse_h.sparse_hierarchy(embedding, geodesics, c0=c0, key=key, **kw)
        return Hierarchy(tuple(lv), np.asarray(embedding, np.float64))
    given = sorted(k for k, v in sparse_opts.items() if v is not None)
    if given:
        raise FxspaceError(
            f"{', '.join(given)}: options of a sparse hierarchy (a NeighbourGraph); with "
            "geodesics every level down to c = T is built"
        )
    kw = {k: v for k, v in dense_opts.items() if v is not None}
    return _dense_h.build_hierarchy(embedding, geodesics, c0=c0, key=key, **kw)


def relink(hierarchy: Hierarchy, paths, rho_scale: float = 0.5, *, bridges: bool = False,
           max_link_centres: int | None = None) -> Hierarchy:  # fmt: skip
    """A dense hierarchy's levels with their links made again at ρ = ``rho_scale`` × each
    level's centre spacing (``bridges`` as in `build_hierarchy`): how a ρ chosen by
    `link_radius_sweep` / `choose_link_scale` is applied without clustering again."""
    if _is_sparse(hierarchy) or isinstance(paths, NeighbourGraph):
        raise FxspaceError(
            "relink applies to a dense hierarchy with its Geodesics; a sparse hierarchy "
            "takes its links from build_hierarchy(..., links=True)"
        )
    return _dense_h.relink(hierarchy, paths, rho_scale, bridges=bridges,
                           max_link_centres=max_link_centres)  # fmt: skip


def hierarchy_to_arrays(h: Hierarchy) -> dict[str, np.ndarray]:
    """A flat ``{name: array}`` of a dense or sparse `Hierarchy` (for ``.npz`` files and
    run caches; no pickles); `hierarchy_from_arrays` inverts it. A sparse one keeps
    its links in CSR form and drops the FCM results (``fcm = None``).

    **Example:**

    ```python
    np.savez("h.npz", **fx.hierarchy_to_arrays(h))
    h2 = fx.hierarchy_from_arrays(np.load("h.npz"))
    ```
    """
    if _is_sparse(h):
        out = _sparse_h.sparse_levels_to_arrays(h.levels)
        out["embedding"] = np.asarray(h.embedding, np.float64)
        out["sparse"] = np.asarray(True)
        return out
    return _dense_h.hierarchy_to_arrays(h)


def hierarchy_from_arrays(a) -> Hierarchy:
    """The `Hierarchy` (dense or sparse) that `hierarchy_to_arrays` stored."""
    if not (isinstance(a, Mapping) or hasattr(a, "files")):
        raise FxspaceError(
            f"a must be the arrays of hierarchy_to_arrays (a dict or an NpzFile), got "
            f"{type(a).__name__}"
        )
    if "sparse" in a:
        return Hierarchy(tuple(_sparse_h.sparse_levels_from_arrays(a)), np.asarray(a["embedding"]))
    return _dense_h.hierarchy_from_arrays(a)


def center_links(
    embedding, paths, center_frames, rho: float | None = None, *, bridge: bool | None = None,
    exact: bool | None = None,
) -> tuple[Any, Any]:  # fmt: skip
    """Links between centres (Kim & Jung §3.5: the path between two centres passes no
    other centre's ρ-disc) and the bridges that keep the level connected.

    **Arguments:** `embedding` ``(T, 2)``; `paths` the frame graph's ``Geodesics`` (dense:
    ``(c, c)`` bool matrices) or a `NeighbourGraph` (sparse: ``csr_array``\\ s); the
    `center_frames`; `rho` (dense: required; sparse: default the level's spacing rule);
    `bridge` adds the bridges (dense: default False, the paper's rule alone; sparse
    links always carry theirs); `exact` (dense) every segment against every centre
    (default: up to `EXACT_CENTRES` centres; above, a conservative near-list test).

    **Returns:** ``(links, bridges)``.
    """
    if isinstance(paths, NeighbourGraph):
        if bridge is False:
            raise FxspaceError("bridge=False applies to dense links (geodesics)")
        lk, br = _sparse_h.sparse_links(paths, embedding, np.asarray(center_frames), rho)
        return lk, br
    if rho is None:
        raise FxspaceError("rho is required for dense links (the link radius, in 2-D units)")
    return _dense_links.center_links(
        embedding, paths, center_frames, rho, bridge=bool(bridge), exact=exact
    )


def frame_path(paths, key_frames: Sequence[int]) -> np.ndarray:
    """Frames along shortest paths through ``key_frames`` in order (no repeats at the
    joins): next hops of the ``Geodesics``, or Dijkstra on a `NeighbourGraph`."""
    if isinstance(paths, NeighbourGraph):
        return _sparse_h.sparse_route(paths, key_frames)
    return _dense.frame_path(paths, key_frames)


def make_route(
    h: Hierarchy, paths, level: int, centres: Sequence[int], anchors: Sequence[int] | None = None
) -> Route:
    """Pick key centres at ``level``; consecutive centres must be linked.

    **Arguments:** `h` a `Hierarchy`; `paths` its frames' ``Geodesics`` (dense) or
    `NeighbourGraph` (sparse); `level` (0 = coarsest); `centres` the key centres in
    order; `anchors` the animator's frames kept through refinement (default the key
    frames).

    **Returns:** a `Route` whose `frames` join the key frames by shortest paths. Raises
    `NavigationError` naming the first unlinked pair and the centres linked to its first
    member.
    """
    if _sparse_paths(h, paths):
        return _sparse.sparse_make_route(h.levels, paths, level, centres, anchors)
    return _dense.make_route(h, paths, level, centres, anchors=anchors)


def bridge_keys(
    h: Hierarchy, paths, level: int, keys: Sequence[int]
) -> tuple[list[int], list[str]]:
    """Make a key sequence valid at ``level``: a key repeating its predecessor is dropped;
    a pair that is not linked is joined by the shortest chain of links between them
    (Dijkstra over the level's links, weighted by geodesic length). Used after inserting,
    replacing or deleting a key.

    **Returns:** ``(keys, notes)``: every consecutive pair of ``keys`` is linked; one note
    per change (e.g. ``"3 → 7 not linked: bridged via 5"``). Raises `NavigationError` for
    an unknown centre or when two keys lie in parts the links cannot join.
    """
    if _sparse_paths(h, paths):
        return _sparse.sparse_bridge_keys(h.levels, paths, level, keys)
    return _dense.bridge_keys(h, paths, level, keys)


def path_candidates(
    h: Hierarchy, level: int, frames: Sequence[int], radius: float | None = None
) -> np.ndarray:
    """Centres of ``level`` whose frame lies within ``radius`` (2-D; default the level's
    link radius ρ) of the path ``frames``, ordered along it."""
    if _is_sparse(h):
        return _sparse.sparse_path_candidates(h.levels, h.embedding, level, frames, radius)
    return _dense.path_candidates(h, level, frames, radius)


def refine_route(
    h: Hierarchy,
    paths,
    route: Route,
    picks: Sequence[int] | None = None,
    radius: float | None = None,
) -> Route:
    """Move ``route`` one level finer.

    With ``picks`` (centres of the finer level) the animator's choice is validated and
    used. Without, the refinement is automatic: each key frame maps to the finer level's
    nearest centre, the candidates near the current path (`path_candidates`) are
    inserted in path order, and any consecutive pair that is not linked is joined by the
    shortest chain of links.
    """
    if _sparse_paths(h, paths):
        return _sparse.sparse_refine_route(h.levels, h.embedding, paths, route, picks, radius)
    return _dense.refine_route(h, paths, route, picks, radius)


def navigate(
    h: Hierarchy, paths, centres: Sequence[int], level: int = 0, to_level: int | None = None
) -> list[Route]:
    """Scripted navigation: pick ``centres`` at ``level`` and refine automatically down to
    ``to_level`` (default the finest; on a sparse hierarchy built with ``finest=True``
    the last route's `frames` are the animation). Returns the route at every level
    visited, coarse to fine.

    **Example:**

    ```python
    keys, _ = fx.bridge_keys(h, es.graph, 0, [0, 4, 9])
    frames = fx.navigate(h, es.graph, keys)[-1].frames
    ```
    """
    if _sparse_paths(h, paths):
        return _sparse.sparse_navigate(h.levels, h.embedding, paths, centres, level, to_level)
    return _dense.navigate(h, paths, centres, level, to_level)
