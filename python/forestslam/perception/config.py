"""Perception parameters (Gupta et al. 2023, Sections 3.1-3.2). Lengths in metres, angles in
radians; field names match the C++ option structs in cpp/forestslam/perception/config.hpp."""

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
class GroundConfig:
    """Approximate progressive morphological filter (PCL), run on the lowest point of every
    `cell_size_m` cell; all points within `cell_height_m` above their cell's ground are ground."""

    cell_size_m: Positive = 0.5
    max_window_cells: PositiveInt = 5  # windows 3, 5 cells (2.5 m: wider than any stem)
    slope: NonNegative = 0.5
    initial_distance_m: NonNegative = 0.2
    max_distance_m: NonNegative = 1.0
    base: Positive = 2.0
    exponential: bool = True
    cell_height_m: NonNegative = 0.2
    # smaller ground islands (stems near the sensor) are dropped
    min_component_cells: NonNegativeInt = 6
    max_range_m: Positive = 30.0  # single scans: ground searched within this XY range


@dataclass
class NormalFilterConfig:
    """Adaptive ring-based normals: rings geomspace(ring_min_m, ring_max_m, rings), per ring
    radius radius_scale * theta_V * (r_in + r_out) / 2 clamped to [min_radius_m, max_radius_m];
    `adaptive=False` uses `fixed_radius_m` everywhere (the paper's ablation)."""

    adaptive: bool = True
    ring_min_m: Positive = 1.0
    ring_max_m: Positive = 40.0
    rings: PositiveInt = 12
    radius_scale: Positive = 1.5
    min_radius_m: Positive = 0.1
    max_radius_m: Positive = 1.0
    fixed_radius_m: Positive = 0.3
    # theta_th: normals within 30 deg of horizontal
    max_normal_angle_rad: Annotated[float, Range(ge=0, le=1.5708)] = 0.5236
    min_neighbours: PositiveInt = 5  # N_min
    max_neighbours: PositiveInt = 32  # nearest neighbours used per normal (speed cap)
    min_height_m: float = 0.3  # band above the local ground searched for stems
    max_height_m: Positive = 8.0
    voxel_m: NonNegative = 0.05  # thinning before normals (0 = none)
    map_voxel_m: NonNegative = 0.1  # coarser thinning for map / tls clouds


@dataclass
class SegmentationConfig:
    """Range-image divide-and-merge, adaptive DBSCAN and SVD stem classification."""

    block_cols: PositiveInt = 32
    beta_min_rad: NonNegative = 0.1745
    max_neighbour_gap_m: NonNegative = 0.5
    max_pixel_gap: NonNegativeInt = 2
    # Near the sensor the voxel thinning leaves several empty columns across one surface: bridge
    # up to this much arc horizontally (0 = only max_pixel_gap).
    max_gap_m: NonNegative = 0.1
    min_votes: PositiveInt = 2
    euclidean_tolerance_m: Positive = 0.2  # coarse 3D clustering of map / tls clouds
    dbscan_k: Positive = 1.25
    dbscan_min_neighbours: PositiveInt = 2
    dbscan_min_eps_m: Positive = 0.08
    dbscan_max_eps_m: Positive = 1.0
    map_dbscan_eps_m: Positive = 0.25
    min_points: PositiveInt = 8
    min_length_m: NonNegative = 0.4
    max_axis_angle_rad: NonNegative = 0.5236
    min_sv_ratio: NonNegative = 1.5
    max_width_m: Positive = 1.5
    merge_xy_m: NonNegative = 0.4
    max_range_m: NonNegative = 30.0  # single scans: stems farther away are ignored (0 = no limit)
    ground_search_m: Positive = 2.0


@dataclass
class DiameterConfig:
    """DBH on the 1.15-1.45 m band (widened around 1.3 m up to band_max_half_m when sparse) by
    the robust circle fit and by PCL's SAC cylinder; the better quality wins. For single scans
    also the silhouette estimate (angular width of each scan line across the stem seen from
    the sensor, +-band_max_half_m around 1.3 m), preferred when its scan lines agree: unlike
    a fit of a one-third arc it does not suffer from range noise."""

    band_low_m: float = 1.15
    band_high_m: float = 1.45
    band_max_half_m: NonNegative = 1.0
    min_band_points: PositiveInt = 20
    min_radius_m: Positive = 0.025
    max_radius_m: Positive = 0.75
    inlier_threshold_m: Positive = 0.03
    min_arc_coverage: Fraction = 0.1
    map_min_arc_coverage: Fraction = 0.25  # `map` clouds: stems seen from many sides
    cylinder_iterations: PositiveInt = 50
    cylinder_max_points: PositiveInt = 100
    cylinder_normal_weight: NonNegative = 0.1
    cylinder_section_low_m: float = 0.5
    cylinder_section_high_m: float = 3.0
    max_lean_rad: NonNegative = 0.35
    silhouette: bool = (
        True  # single scans: stem width seen from the sensor, preferred if consistent
    )
    # An estimate is skipped when one before it decides the DBH anyway: the band circle when
    # an accepted silhouette does, the SAC cylinder (the costliest) when either does; True fits
    # (and reports) every estimate for every stem.
    fit_all: bool = False


@dataclass
class PerceptionConfig:
    """Per-scan perception. `intensity_filter` applies the sensor profile's
    intensity_threshold (skipped when the profile has none or the scan has no intensity)."""

    intensity_filter: bool = True
    # Single scans: the returns the filter removes are evidence: a cluster of every return
    # whose removed returns its geometry shows to be its bark (bright bark facing the sensor
    # under another sensor's intensity scale) takes them back; the stems of the kept returns
    # alone are otherwise unchanged. Off by default (see the C++ PerceptionConfig).
    intensity_as_evidence: bool = False
    ground_voxel_m: Positive = 0.25  # ground output: one point per voxel
    # `map` clouds in which the chain finds no stem (a cropped trunk, a breast-height slice, a
    # stem cut out of a plot, without ground): every 3D cluster whose breast-height section is
    # a circle (at least this share of its band points within the circle's inlier gate) is a
    # stem; points thinned to slice_voxel_m first.
    slice_voxel_m: Positive = 0.01
    slice_min_inlier_ratio: Fraction = 0.5
    ground: GroundConfig = field(default_factory=GroundConfig)
    filter: NormalFilterConfig = field(default_factory=NormalFilterConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    diameter: DiameterConfig = field(default_factory=DiameterConfig)
