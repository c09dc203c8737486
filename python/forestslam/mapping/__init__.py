"""Forest mapping: tree map with fused DBH, voxelized ground map and DTM, figures."""

from forestslam.mapping.config import MappingConfig
from forestslam.mapping.ground_map import GroundMap, dtm_grid, remove_raised_cells, write_dtm
from forestslam.mapping.tree_map import TreeMap, fit_band_circle
from forestslam.mapping.voxel import voxel_downsample

__all__ = [
    "MappingConfig",
    "TreeMap",
    "fit_band_circle",
    "GroundMap",
    "dtm_grid",
    "remove_raised_cells",
    "write_dtm",
    "voxel_downsample",
]
