"""Landmark SLAM: GTSAM iSAM2 with Pose2 keyframes and Point2 trees, robust data association."""

from forestslam.slam.association import AssociationResult, associate
from forestslam.slam.config import SlamConfig
from forestslam.slam.landmark_slam import LandmarkSlam, ScanResult, level_points, planar

__all__ = [
    "SlamConfig",
    "LandmarkSlam",
    "ScanResult",
    "associate",
    "AssociationResult",
    "level_points",
    "planar",
]
