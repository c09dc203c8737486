"""Landmark SLAM: GTSAM iSAM2 with Pose2 keyframes and Point2 trees, robust data association."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "association": ("AssociationResult", "associate"),
        "config": ("SlamConfig",),
        "landmark_slam": ("LandmarkSlam", "ScanResult", "level_points", "planar"),
    },
)
