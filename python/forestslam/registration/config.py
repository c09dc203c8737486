"""Registration parameters. Lengths in metres, angles in radians; names and defaults match the
C++ structs in cpp/forestslam/registration/*.hpp and odometry/odometry_config.hpp
(tests/test_config_parity.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from forestslam.config_utils import (
    Fraction,
    NonNegative,
    NonNegativeInt,
    Positive,
    PositiveInt,
    Range,
)


@dataclass
class TreeMatchConfig:
    """Mutually exclusive nearest stems in XY after the constant-velocity prediction."""

    gate_m: Positive = 1.0
    # < 1: drop pairs whose second-nearest target is within distance / ratio
    ratio: Annotated[float, Range(gt=0, le=1)] = 1.0


@dataclass
class ShapeConfig:
    """Shape-to-shape Gaussian registration (Eq. 3) over x, y, yaw with a pair consensus."""

    min_sigma_m: Positive = 0.05
    consensus_tolerance_m: Positive = 0.3
    inlier_threshold_m: Positive = 0.5
    max_consensus_pairs: PositiveInt = 2000
    max_iterations: PositiveInt = 50
    min_inliers_not_degenerate: NonNegativeInt = 3


@dataclass
class IcpConfig:
    """Point-to-plane ICP, 6 DoF, Huber-weighted Gauss-Newton (defaults measured: see
    point_to_plane_icp.hpp)."""

    max_iterations: PositiveInt = 12
    max_correspondence_m: Positive = 1.0
    final_correspondence_m: Positive = 0.3
    shrink_iterations: NonNegativeInt = 3
    coarse_stride: PositiveInt = 1  # every n-th source point while the distance shrinks
    huber_m: Positive = 0.05
    translation_tolerance_m: NonNegative = 5e-4
    rotation_tolerance_rad: NonNegative = 5e-5
    min_correspondences: PositiveInt = 20
    degeneracy_threshold: NonNegative = 2e-3
    degeneracy_length_m: Positive = 10.0
    normal_k: Annotated[int, Range(ge=3)] = 10  # target normals from this many nearest neighbours


@dataclass
class FpfhConfig:
    """Baseline: FPFH + RANSAC (SampleConsensusPrerejective) + point-to-plane ICP."""

    voxel_m: Positive = 0.25
    normal_radius_m: Positive = 0.75
    feature_radius_m: Positive = 1.25
    ransac_iterations: PositiveInt = 20000
    correspondence_randomness: PositiveInt = 3
    similarity_threshold: Fraction = 0.9
    inlier_distance_m: Positive = 0.5
    inlier_fraction: Fraction = 0.25
    seed: NonNegativeInt = 42


@dataclass
class RegistrationConfig:
    trees: TreeMatchConfig = field(default_factory=TreeMatchConfig)
    shape: ShapeConfig = field(default_factory=ShapeConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    fpfh: FpfhConfig = field(default_factory=FpfhConfig)
