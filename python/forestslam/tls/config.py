"""Configuration of MLS-to-TLS plot mapping (Shao et al. 2020)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class FeatureConfig:
    """Per-frame features: DoG keypoints (real) and ring stem centres (virtual)."""

    max_keypoints: int = 200
    keypoint_voxel_m: float = 0.08
    sigma_small_m: float = 0.15
    sigma_large_m: float = 0.30
    nms_radius_m: float = 0.6
    min_diameter_m: float = 0.06
    max_diameter_m: float = 1.0


@dataclass
class MapConfig:
    """Global incremental map: TLS reference plus accepted MLS frames, voxelized."""

    voxel_m: float = 0.03
    # A frame joins the map when its stem-centre (virtual) residual RMS is below this and it
    # has enough virtual pairs; frames without stems still get a pose but never join the map.
    accept_virtual_rms_m: float = 0.03
    accept_min_virtual_inliers: int = 24
    frame_min_range_m: float = 1.0  # the operator carrying the scanner is not mapped
    frame_max_range_m: float = 25.0
    # The LM target (KD-tree) is rebuilt after this many accepted frames (cost bounded).
    rebuild_every_frames: int = 10
    max_points: int = 30_000_000


@dataclass
class RegistrationConfig:
    ndt_voxel_m: float = 0.3
    ndt_resolution_m: float = 1.0
    lm_virtual_gate_m: float = 0.1
    lm_plane_gate_m: float = 0.25
    lm_robust_scale_m: float = 0.05
    lm_max_rounds: int = 15
    # First-frame coarse alignment by stem positions (when no --initial-pose is given).
    coarse_distance_tolerance_m: float = 0.25
    coarse_inlier_m: float = 0.35
    coarse_min_stems: int = 3
    coarse_max_frames: int = 20  # frames tried for the coarse alignment before giving up


@dataclass
class TreeConfig:
    """Stems and DBH of the merged cloud; stem coverage at breast height."""

    band_m: tuple[float, float] = (1.2, 1.4)
    ground_cell_m: float = 1.0
    coverage_sectors: int = 36
    coverage_tolerance_m: float = 0.03


@dataclass
class TlsConfig:
    features: FeatureConfig = field(default_factory=FeatureConfig)
    map: MapConfig = field(default_factory=MapConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    trees: TreeConfig = field(default_factory=TreeConfig)
    frame_step: int = 1  # process every n-th MLS frame
