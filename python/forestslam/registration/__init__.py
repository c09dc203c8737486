"""Scan registration: tree correspondences, shape-to-shape Gaussian registration of stems,
point-to-plane ICP, the FPFH + RANSAC baseline and (when built) stem-centre LM. Every method
returns a `RegistrationResult` with T_target_source (4,4), covariance (6,6), converged,
degenerate, inliers, iterations, rmse."""

from forestslam.registration.config import (
    FpfhConfig,
    IcpConfig,
    RegistrationConfig,
    ShapeConfig,
    TreeMatchConfig,
)
from forestslam.registration.facade import (
    PlaneTarget,
    icp_point_to_plane,
    match_trees,
    register_fpfh,
    register_shapes,
    voxel_downsample,
)

__all__ = [
    "FpfhConfig",
    "IcpConfig",
    "PlaneTarget",
    "RegistrationConfig",
    "ShapeConfig",
    "TreeMatchConfig",
    "icp_point_to_plane",
    "match_trees",
    "register_fpfh",
    "register_shapes",
    "voxel_downsample",
]
