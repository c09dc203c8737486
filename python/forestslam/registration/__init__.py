"""Scan registration: tree correspondences, shape-to-shape Gaussian registration of stems,
point-to-plane ICP, the FPFH + RANSAC baseline and (when built) stem-centre LM. Every method
returns a `RegistrationResult` with T_target_source (4,4), covariance (6,6), converged,
degenerate, inliers, iterations, rmse."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "config": (
            "FpfhConfig",
            "IcpConfig",
            "RegistrationConfig",
            "ShapeConfig",
            "TreeMatchConfig",
        ),
        "facade": (
            "PlaneTarget",
            "icp_point_to_plane",
            "match_trees",
            "register_fpfh",
            "register_shapes",
            "voxel_downsample",
        ),
    },
)
