"""Point-cloud and trajectory I/O without ROS."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "bags": ("write_scans",),
        "clouds": ("read_cloud", "write_cloud"),
        "readers": ("READERS", "ScanStream", "open_source", "read_scans"),
        "scan": ("Scan",),
        "source": ("ReadStats", "ScanSource", "TopicInfo"),
        "trajectory": ("read_kitti", "read_tum", "write_kitti", "write_tum"),
        "trees": ("read_trees_csv", "write_trees_csv", "write_trees_geojson"),
    },
)
