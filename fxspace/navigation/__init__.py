"""Hierarchical navigation of an expression space (Kim & Jung §3–4): fuzzy c-means
levels, links between centres, routes refined level by level, playback — one model at
every size: `Level` / `Hierarchy`, written once against the frames' *paths*
(`fxspace.expression.Paths`: `Geodesics` or a `NeighbourGraph`), options on solver
objects (`FuzzyCMeans`, `TruncatedFuzzyCMeans`, `LinkRule`).
"""

from fxspace.navigation._hierarchy import FuzzyCMeans as FuzzyCMeans
from fxspace.navigation._hierarchy import TruncatedFuzzyCMeans as TruncatedFuzzyCMeans
from fxspace.navigation._hierarchy import build_hierarchy as build_hierarchy
from fxspace.navigation._hierarchy import cold_levels as cold_levels
from fxspace.navigation._hierarchy import finest_level as finest_level
from fxspace.navigation._hierarchy import frame_links as frame_links
from fxspace.navigation._hierarchy import nearest_frames as nearest_frames
from fxspace.navigation._hierarchy import relink as relink
from fxspace.navigation._hierarchy import split_centers as split_centers
from fxspace.navigation._index import GridIndex as GridIndex
from fxspace.navigation._level import Hierarchy as Hierarchy
from fxspace.navigation._level import Level as Level
from fxspace.navigation._level import LinkRadiusSweep as LinkRadiusSweep
from fxspace.navigation._level import SparseLevel as SparseLevel
from fxspace.navigation._level import hierarchy_from_arrays as hierarchy_from_arrays
from fxspace.navigation._level import hierarchy_to_arrays as hierarchy_to_arrays
from fxspace.navigation._level import is_sparse as is_sparse
from fxspace.navigation._level import level_sizes as level_sizes
from fxspace.navigation._level import link_components as link_components
from fxspace.navigation._level import link_graph_connected as link_graph_connected
from fxspace.navigation._level import link_pairs as link_pairs
from fxspace.navigation._links import EXACT_CENTRES as EXACT_CENTRES
from fxspace.navigation._links import LINK_SCALES as LINK_SCALES
from fxspace.navigation._links import LinkRule as LinkRule
from fxspace.navigation._links import center_links as center_links
from fxspace.navigation._links import default_link_radius as default_link_radius
from fxspace.navigation._links import link_clearance as link_clearance
from fxspace.navigation._playback import Playback as Playback
from fxspace.navigation._playback import playback as playback
from fxspace.navigation._playback import rigid_align as rigid_align
from fxspace.navigation._rho import choose_link_scale as choose_link_scale
from fxspace.navigation._rho import link_radius_sweep as link_radius_sweep
from fxspace.navigation._routes import NavigationError as NavigationError
from fxspace.navigation._routes import Route as Route
from fxspace.navigation._routes import bridge_keys as bridge_keys
from fxspace.navigation._routes import frame_path as frame_path
from fxspace.navigation._routes import is_graph_walk as is_graph_walk
from fxspace.navigation._routes import make_route as make_route
from fxspace.navigation._routes import navigate as navigate
from fxspace.navigation._routes import path_candidates as path_candidates
from fxspace.navigation._routes import refine_route as refine_route
from fxspace.navigation._space import SWEEP_THRESHOLDS as SWEEP_THRESHOLDS
from fxspace.navigation._space import THRESHOLD_CRITERIA as THRESHOLD_CRITERIA
from fxspace.navigation._space import NavigationSpace as NavigationSpace
from fxspace.navigation._space import navigation_space as navigation_space
from fxspace.navigation._space import resolve_threshold as resolve_threshold
from fxspace.navigation._space import threshold_from_run as threshold_from_run

__all__ = [
    "EXACT_CENTRES",
    "LINK_SCALES",
    "LinkRadiusSweep",
    "LinkRule",
    "FuzzyCMeans",
    "TruncatedFuzzyCMeans",
    "choose_link_scale",
    "link_clearance",
    "link_components",
    "link_radius_sweep",
    "relink",
    "NavigationSpace",
    "SWEEP_THRESHOLDS",
    "THRESHOLD_CRITERIA",
    "navigation_space",
    "resolve_threshold",
    "threshold_from_run",
    "GridIndex",
    "Hierarchy",
    "Level",
    "build_hierarchy",
    "cold_levels",
    "hierarchy_from_arrays",
    "hierarchy_to_arrays",
    "is_sparse",
    "center_links",
    "default_link_radius",
    "level_sizes",
    "link_graph_connected",
    "link_pairs",
    "nearest_frames",
    "split_centers",
    "NavigationError",
    "Route",
    "bridge_keys",
    "frame_path",
    "is_graph_walk",
    "make_route",
    "navigate",
    "path_candidates",
    "refine_route",
    "Playback",
    "playback",
    "rigid_align",
    "SparseLevel",
    "frame_links",
    "finest_level",
]
