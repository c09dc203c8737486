"""Odometry parameters. Lengths in metres, angles in degrees where the name says so. The C++
struct forestslam::odometry::OdometryConfig holds the same fields with the same defaults
(tests/test_config_parity.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

from forestslam.config_utils import NonNegative, NonNegativeInt, Positive, PositiveInt
from forestslam.registration.config import RegistrationConfig

Method = Literal["trees", "icp", "fpfh", "stem_centre_lm"]
Mode = Literal["local_map", "scan_to_scan"]
METHODS, MODES = get_args(Method), get_args(Mode)


@dataclass
class OdometryConfig:
    """method: "trees" (tree correspondences + shape-to-shape + point-to-plane ICP), "icp"
    (point-to-plane ICP from the constant-velocity prediction), "fpfh" (FPFH + RANSAC + ICP
    baseline on the whole scan), "stem_centre_lm" (Shao et al.; when built).
    mode: "local_map" registers each scan onto keyframes near it, "scan_to_scan" onto the
    previous scan."""

    method: Method = "trees"
    mode: Mode = "local_map"
    deskew: bool = True  # spinning scans with per-point time, constant-velocity motion
    # fewer matched stems: ICP with the velocity prior, pose marked degraded
    min_stems: NonNegativeInt = 2
    # Source cloud for ICP: stem points + ground points, thinned to this voxel, at most this many.
    source_voxel_m: Positive = 0.2
    max_source_points: PositiveInt = 1200
    # Local map: keyframes every keyframe_distance_m / keyframe_yaw_deg, the last
    # local_map_keyframes kept, cropped to local_map_radius_m around the sensor.
    keyframe_distance_m: NonNegative = 1.0
    keyframe_yaw_deg: NonNegative = 10.0
    local_map_keyframes: PositiveInt = 10
    local_map_radius_m: Positive = 40.0
    map_voxel_m: Positive = 0.15
    stem_merge_m: NonNegative = 0.5  # map stems closer than this in XY are one tree (newest kept)
    # Velocity prior of the fallback ICP (1-sigma per scan), and the largest correction from the
    # prediction accepted before the pose is declared degraded and the prediction kept.
    prior_sigma_m: Positive = 0.1
    prior_sigma_deg: Positive = 1.0
    max_correction_m: Positive = 1.5
    max_correction_deg: Positive = 15.0
    max_speed_mps: Positive = 5.0  # the velocity prior is clamped to these
    max_turn_rate_dps: Positive = 90.0
    # A longer gap between scans (or a stamp jumping back) restarts the motion model: no
    # prediction is multiplied by the gap; a warning names the gap and the scan.
    max_stamp_gap_s: Positive = 1.0
    fpfh_max_points: PositiveInt = 6000  # FPFH baseline: whole scan, voxelised, at most this many
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
