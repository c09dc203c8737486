"""LiDAR odometry: `Odometry(sensor, config=None).step(scan) -> OdometryStep`."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "config": ("METHODS", "MODES", "OdometryConfig"),
        "deskew": ("deskew_points",),
        "odometry": ("Odometry", "OdometryStep"),
    },
)
