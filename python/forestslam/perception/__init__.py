"""Per-scan perception: pre-processing, tree-stem segmentation and stem diameter."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "config": ("PerceptionConfig",),
        "pipeline": (
            "GroundSurface",
            "classify_cluster",
            "coarse_clusters",
            "detect",
            "estimate_diameter",
            "filter_normals",
            "ground_surface",
            "intensity_filter",
            "refine_cluster",
            "segment_ground",
            "sensor_geometry",
        ),
        "stems": ("Stems",),
    },
)
