"""Evaluation of trajectories and tree maps against ground truth.

Trajectories: timestamps associated, SE(3) Umeyama alignment of positions, ATE RMSE, KITTI-style
relative translation error over 10 m segments, final drift. Tree maps: the estimate moved by the
same alignment, matched to truth one-to-one by the Hungarian method inside a distance gate.
Ground (map3d runs): DTM cells and ground-map points moved by the same alignment against the
simulator's terrain, rebuilt from the truth's scenario.yaml.
"""

from forestslam.evaluation.ground import dtm_cells, height_errors, load_truth_terrain
from forestslam.evaluation.trajectory import associate, trajectory_errors, umeyama
from forestslam.evaluation.trees import tree_errors

__all__ = [
    "associate",
    "umeyama",
    "trajectory_errors",
    "tree_errors",
    "dtm_cells",
    "height_errors",
    "load_truth_terrain",
]
