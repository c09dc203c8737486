"""Per-scan perception: pre-processing, tree-stem segmentation and stem diameter."""

from forestslam.perception.config import PerceptionConfig
from forestslam.perception.pipeline import (
    GroundSurface,
    classify_cluster,
    coarse_clusters,
    detect,
    estimate_diameter,
    filter_normals,
    ground_surface,
    intensity_filter,
    refine_cluster,
    segment_ground,
    sensor_geometry,
)
from forestslam.perception.stems import Stems

__all__ = [
    "PerceptionConfig",
    "Stems",
    "GroundSurface",
    "detect",
    "intensity_filter",
    "segment_ground",
    "ground_surface",
    "filter_normals",
    "coarse_clusters",
    "refine_cluster",
    "classify_cluster",
    "estimate_diameter",
    "sensor_geometry",
]
