"""Point-cloud and trajectory I/O without ROS."""

from forestslam.io.bags import write_scans
from forestslam.io.clouds import read_cloud, write_cloud
from forestslam.io.readers import READERS, ScanStream, open_source, read_scans
from forestslam.io.scan import Scan
from forestslam.io.source import ReadStats, ScanSource, TopicInfo
from forestslam.io.trajectory import read_kitti, read_tum, write_kitti, write_tum
from forestslam.io.trees import read_trees_csv, write_trees_csv, write_trees_geojson

__all__ = [
    "READERS",
    "ReadStats",
    "Scan",
    "ScanSource",
    "ScanStream",
    "TopicInfo",
    "open_source",
    "read_cloud",
    "read_kitti",
    "read_scans",
    "read_trees_csv",
    "read_tum",
    "write_cloud",
    "write_kitti",
    "write_scans",
    "write_trees_csv",
    "write_trees_geojson",
    "write_tum",
]
