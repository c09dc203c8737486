"""Per-scan perception: pre-processing, tree-stem segmentation and stem diameter."""

from forestslam.perception.config import PerceptionConfig
from forestslam.perception.pipeline import (
    classify_cluster,
    coarse_clusters,
    detect,
    estimate_diameter,
    filter_normals,
    intensity_filter,
    refine_cluster,
    segment_ground,
    sensor_geometry,
)
from forestslam.perception.stems import Stems

__all__ = [
    "PerceptionConfig",
    "Stems",
    "detect",
    "intensity_filter",
    "segment_ground",
    "filter_normals",
    "coarse_clusters",
    "refine_cluster",
    "classify_cluster",
    "estimate_diameter",
    "sensor_geometry",
]
