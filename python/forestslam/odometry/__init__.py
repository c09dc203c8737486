"""LiDAR odometry: `Odometry(sensor, config=None).step(scan) -> OdometryStep`."""

from forestslam.odometry.config import METHODS, MODES, OdometryConfig
from forestslam.odometry.deskew import deskew_points
from forestslam.odometry.odometry import Odometry, OdometryStep

__all__ = ["METHODS", "MODES", "Odometry", "OdometryConfig", "OdometryStep", "deskew_points"]
