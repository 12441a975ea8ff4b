"""Expression space (Kim & Jung): marker features → ε-graph → geodesics → classical MDS →
Pearson r, and threshold sweeps over that one chain.
"""

from fxspace.expression._blocks import neighbourhood_graph_blocks as neighbourhood_graph_blocks
from fxspace.expression._features import PAIR_WEIGHT as PAIR_WEIGHT
from fxspace.expression._features import clean_frames as clean_frames
from fxspace.expression._features import distance_features as distance_features
from fxspace.expression._features import pairwise_distances as pairwise_distances
from fxspace.expression._geodesic import Geodesics as Geodesics
from fxspace.expression._geodesic import check_connected as check_connected
from fxspace.expression._geodesic import connected_components as connected_components
from fxspace.expression._geodesic import connecting_threshold as connecting_threshold
from fxspace.expression._geodesic import epsilon_graph as epsilon_graph
from fxspace.expression._geodesic import floyd_warshall as floyd_warshall
from fxspace.expression._geodesic import geodesic_distances as geodesic_distances
from fxspace.expression._geodesic import next_hops as next_hops
from fxspace.expression._geodesic import shortest_path as shortest_path
from fxspace.expression._join import Joins as Joins
from fxspace.expression._join import join_components as join_components
from fxspace.expression._landmark import LandmarkBasis as LandmarkBasis
from fxspace.expression._landmark import LandmarkGeodesics as LandmarkGeodesics
from fxspace.expression._landmark import farthest_point_landmarks as farthest_point_landmarks
from fxspace.expression._landmark import landmark_basis as landmark_basis
from fxspace.expression._landmark import landmark_geodesics as landmark_geodesics
from fxspace.expression._landmark import landmark_mds as landmark_mds
from fxspace.expression._landmark import landmark_score as landmark_score
from fxspace.expression._landmark import place_frames as place_frames
from fxspace.expression._mds import MDSResult as MDSResult
from fxspace.expression._mds import classical_mds as classical_mds
from fxspace.expression._mds import pearson_score as pearson_score
from fxspace.expression._missing import GapFill as GapFill
from fxspace.expression._missing import fill_gaps as fill_gaps
from fxspace.expression._missing import missing_report as missing_report
from fxspace.expression._missing import require_complete as require_complete
from fxspace.expression._paths import Paths as Paths
from fxspace.expression._space import ExpressionSpace as ExpressionSpace
from fxspace.expression._space import embed_graph as embed_graph
from fxspace.expression._space import expression_space as expression_space
from fxspace.expression._sparse import KnnQuality as KnnQuality
from fxspace.expression._sparse import NeighbourGraph as NeighbourGraph
from fxspace.expression._sparse import check_sparse_connected as check_sparse_connected
from fxspace.expression._sparse import dijkstra_csr as dijkstra_csr
from fxspace.expression._sparse import graph_from_dense as graph_from_dense
from fxspace.expression._sparse import knn_quality as knn_quality
from fxspace.expression._sparse import knn_recall as knn_recall
from fxspace.expression._sparse import neighbourhood_graph as neighbourhood_graph
from fxspace.expression._sparse import sparse_components as sparse_components
from fxspace.expression._sparse import to_scipy as to_scipy
from fxspace.expression._sweep import CRITERIA as CRITERIA
from fxspace.expression._sweep import SweepResult as SweepResult
from fxspace.expression._sweep import bridge_parts as bridge_parts
from fxspace.expression._sweep import choose_threshold as choose_threshold
from fxspace.expression._sweep import sweep_message as sweep_message
from fxspace.expression._sweep import threshold_grid as threshold_grid
from fxspace.expression._sweep import threshold_sweep as threshold_sweep

__all__ = [
    "ExpressionSpace",
    "expression_space",
    "clean_frames",
    "distance_features",
    "pairwise_distances",
    "Geodesics",
    "check_connected",
    "connected_components",
    "connecting_threshold",
    "epsilon_graph",
    "floyd_warshall",
    "geodesic_distances",
    "next_hops",
    "shortest_path",
    "MDSResult",
    "LandmarkBasis",
    "LandmarkGeodesics",
    "farthest_point_landmarks",
    "landmark_basis",
    "landmark_geodesics",
    "landmark_mds",
    "landmark_score",
    "place_frames",
    "NeighbourGraph",
    "Paths",
    "check_sparse_connected",
    "KnnQuality",
    "knn_quality",
    "knn_recall",
    "neighbourhood_graph_blocks",
    "Joins",
    "join_components",
    "graph_from_dense",
    "neighbourhood_graph",
    "sparse_components",
    "to_scipy",
    "dijkstra_csr",
    "GapFill",
    "fill_gaps",
    "missing_report",
    "require_complete",
    "classical_mds",
    "pearson_score",
    "CRITERIA",
    "PAIR_WEIGHT",
    "embed_graph",
    "sweep_message",
    "bridge_parts",
    "SweepResult",
    "choose_threshold",
    "threshold_grid",
    "threshold_sweep",
]
