"""Registration parameters. Lengths in metres, angles in radians; names and defaults match the
C++ structs in cpp/forestslam/registration/*.hpp and odometry/odometry_config.hpp
(tests/test_config_parity.py)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class TreeMatchConfig:
    """Mutually exclusive nearest stems in XY after the constant-velocity prediction."""

    gate_m: float = 1.0
    ratio: float = 1.0  # < 1: drop pairs whose second-nearest target is within distance / ratio


@dataclass
class ShapeConfig:
    """Shape-to-shape Gaussian registration (Eq. 3) over x, y, yaw with a pair consensus."""

    min_sigma_m: float = 0.05
    consensus_tolerance_m: float = 0.3
    inlier_threshold_m: float = 0.5
    max_consensus_pairs: int = 2000
    max_iterations: int = 50
    min_inliers_not_degenerate: int = 3


@dataclass
class IcpConfig:
    """Point-to-plane ICP, 6 DoF, Huber-weighted Gauss-Newton (defaults measured: see
    point_to_plane_icp.hpp)."""

    max_iterations: int = 12
    max_correspondence_m: float = 1.0
    final_correspondence_m: float = 0.3
    shrink_iterations: int = 3
    huber_m: float = 0.05
    translation_tolerance_m: float = 5e-4
    rotation_tolerance_rad: float = 5e-5
    min_correspondences: int = 20
    degeneracy_threshold: float = 2e-3
    degeneracy_length_m: float = 10.0
    normal_k: int = 10  # target normals from this many nearest neighbours


@dataclass
class FpfhConfig:
    """Baseline: FPFH + RANSAC (SampleConsensusPrerejective) + point-to-plane ICP."""

    voxel_m: float = 0.25
    normal_radius_m: float = 0.75
    feature_radius_m: float = 1.25
    ransac_iterations: int = 20000
    correspondence_randomness: int = 3
    similarity_threshold: float = 0.9
    inlier_distance_m: float = 0.5
    inlier_fraction: float = 0.25
    seed: int = 42


@dataclass
class RegistrationConfig:
    trees: TreeMatchConfig = field(default_factory=TreeMatchConfig)
    shape: ShapeConfig = field(default_factory=ShapeConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    fpfh: FpfhConfig = field(default_factory=FpfhConfig)
