"""Forest mapping: tree map with fused DBH, voxelized ground map and DTM, figures."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "config": ("MappingConfig",),
        "ground_map": ("GroundMap", "dtm_grid", "remove_raised_cells", "write_dtm"),
        "tree_map": ("TreeMap", "fit_band_circle"),
        "voxel": ("voxel_downsample",),
    },
)
