"""Evaluation of trajectories and tree maps against ground truth.

Trajectories: timestamps associated, SE(3) Umeyama alignment of positions, ATE RMSE, KITTI-style
relative translation error over 10 m segments, final drift. Tree maps: the estimate moved by the
same alignment, matched to truth one-to-one by the Hungarian method inside a distance gate.
Ground (map3d runs): DTM cells and ground-map points moved by the same alignment against the
simulator's terrain, rebuilt from the truth's scenario.yaml.
"""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "ground": ("dtm_cells", "height_errors", "load_truth_terrain"),
        "trajectory": ("associate", "trajectory_errors", "umeyama"),
        "trees": ("tree_errors",),
    },
)
