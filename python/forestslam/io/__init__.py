"""Point-cloud and trajectory I/O without ROS."""

from forestslam.io.scan import Scan
from forestslam.io.trajectory import read_kitti, read_tum, write_kitti, write_tum

__all__ = ["Scan", "read_tum", "write_tum", "read_kitti", "write_kitti"]
