"""Global localization against a prior tree map by Delaunay triangle stars (Li et al.).

>>> tree_map = build_map(map_xy)                 # (M,2) trunk positions
>>> loc = localize(tree_map, local_xy)           # (K,2) trunks seen locally
>>> loc.x, loc.y, loc.yaw, loc.rejected
"""

from forestslam.localization.config import LocalizationConfig
from forestslam.localization.localize import (
    Localization,
    aggregate_stems,
    chain_significance,
    extract_trunks,
    localize,
    merge_close,
)
from forestslam.localization.tree_map import MAP_FORMAT, TreeMap, build_map, load_map

__all__ = [
    "MAP_FORMAT",
    "Localization",
    "LocalizationConfig",
    "TreeMap",
    "aggregate_stems",
    "chain_significance",
    "build_map",
    "extract_trunks",
    "load_map",
    "localize",
    "merge_close",
]
