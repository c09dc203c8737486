"""Odometry parameters. Lengths in metres, angles in degrees where the name says so. The C++
struct forestslam::odometry::OdometryConfig holds the same fields with the same defaults
(tests/test_config_parity.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

from forestslam.registration.config import RegistrationConfig

METHODS = ("trees", "icp", "fpfh", "stem_centre_lm")
MODES = ("local_map", "scan_to_scan")


@dataclass
class OdometryConfig:
    """method: "trees" (tree correspondences + shape-to-shape + point-to-plane ICP), "icp"
    (point-to-plane ICP from the constant-velocity prediction), "fpfh" (FPFH + RANSAC + ICP
    baseline on the whole scan), "stem_centre_lm" (Shao et al.; when built).
    mode: "local_map" registers each scan onto keyframes near it, "scan_to_scan" onto the
    previous scan."""

    method: str = "trees"
    mode: str = "local_map"
    deskew: bool = True  # spinning scans with per-point time, constant-velocity motion
    min_stems: int = 2  # fewer matched stems: ICP with the velocity prior, pose marked degraded
    # Source cloud for ICP: stem points + ground points, thinned to this voxel, at most this many.
    source_voxel_m: float = 0.2
    max_source_points: int = 1200
    # Local map: keyframes every keyframe_distance_m / keyframe_yaw_deg, the last
    # local_map_keyframes kept, cropped to local_map_radius_m around the sensor.
    keyframe_distance_m: float = 1.0
    keyframe_yaw_deg: float = 10.0
    local_map_keyframes: int = 10
    local_map_radius_m: float = 40.0
    map_voxel_m: float = 0.15
    stem_merge_m: float = 0.5  # map stems closer than this in XY are one tree (newest kept)
    # Velocity prior of the fallback ICP (1-sigma per scan), and the largest correction from the
    # prediction accepted before the pose is declared degraded and the prediction kept.
    prior_sigma_m: float = 0.1
    prior_sigma_deg: float = 1.0
    max_correction_m: float = 1.5
    max_correction_deg: float = 15.0
    max_speed_mps: float = 5.0  # the velocity prior is clamped to these
    max_turn_rate_dps: float = 90.0
    # A longer gap between scans (or a stamp jumping back) restarts the motion model: no
    # prediction is multiplied by the gap; a warning names the gap and the scan.
    max_stamp_gap_s: float = 1.0
    fpfh_max_points: int = 6000  # FPFH baseline: whole scan, voxelised, at most this many
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
