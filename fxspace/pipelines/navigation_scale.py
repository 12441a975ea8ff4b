"""Navigation at scale: the navigation pipeline (`fxspace.pipelines.navigation`) with
defaults for 10⁴–10⁵ frames — the k-NN graph (``[graph] kind = "knn"``), landmark
geodesics and landmark MDS, fuzzy c-means with each frame's nearest centres, the same
links by the paper's rule and the same routes. ``experiment = "navigation_scale"`` in
``configs/navigation_scale.toml`` selects this name; every table and key is the
navigation pipeline's.
"""

from __future__ import annotations

import dataclasses

from fxspace.datasets import FaceData
from fxspace.pipelines import navigation as _nav
from fxspace.pipelines.navigation import (
    APP,
    STAGES,
    NavConfig,
    NavSpace,
    auto_key_centres,
    load_space,
    prepare_app,
    run,
)

__all__ = ["APP", "Config", "GraphConfig", "HierarchyConfig", "NavConfig", "NavSpace", "STAGES",
           "prepare_app", "run", "load_space", "auto_key_centres"]  # fmt: skip


@dataclasses.dataclass(frozen=True)
class GraphConfig(_nav.GraphConfig):
    """`fxspace.pipelines.navigation.GraphConfig` with the k-NN graph by default."""

    kind: str = "knn"


@dataclasses.dataclass(frozen=True)
class HierarchyConfig(_nav.HierarchyConfig):
    """`fxspace.pipelines.navigation.HierarchyConfig` with five FCM levels by default."""

    levels: int = 5


@dataclasses.dataclass(frozen=True)
class Config(_nav.Config):
    """The navigation pipeline's config with the scale defaults: 20 000 synthetic
    frames, a k-NN graph, five FCM levels and the level where every frame is a centre."""

    data: FaceData = FaceData(source="synthetic", synthetic_frames=20000)
    graph: GraphConfig = GraphConfig()
    hierarchy: HierarchyConfig = HierarchyConfig()
