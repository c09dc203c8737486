"""Configuration of the tree map (fused DBH), the ground map / DTM and the run's outputs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from forestslam.config_utils import Fraction, NonNegative, Positive, PositiveInt, Range


@dataclass
class MappingConfig:
    # DBH: stem points of the breast-height band above local ground, accumulated in the map
    # frame over a window of scans (the paper: 25 scans / 2.5 s), then one robust circle fit.
    dbh_window_scans: PositiveInt = 25
    dbh_band_m: tuple[NonNegative, Positive] = (1.15, 1.45)
    dbh_min_window_scans: PositiveInt = 5  # a tree leaving view with fewer scans buffered: no fit
    dbh_min_points: Annotated[int, Range(ge=3)] = 15
    dbh_min_m: Positive = 0.04
    dbh_max_m: Positive = 1.5
    circle_inlier_m: Positive = 0.03
    dbh_max_rms_m: Positive = 0.03
    dbh_min_arc_coverage: Fraction = 0.2
    dbh_min_inlier_ratio: Fraction = 0.5  # of the window's points within circle_inlier_m
    # At most this share of a window's points may have been seen through its circle (beyond
    # the middle of their beam's chord): an opaque stem hides them (circles through clumps).
    dbh_max_seen_through: Fraction = 0.15
    # dbh_std_m floor for sections that are not circles (ovality, lobes: a fitted circle and
    # the tape girth differ by a few per cent of the DBH, depending on the side seen).
    dbh_std_floor_rel: Fraction = 0.02
    # Spread of band points across their beams (beam footprint, bark, pose jitter between the
    # scans of a window) for the range-model circle fit; the range spread is estimated.
    dbh_lateral_sigma_m: Positive = 0.01
    # Pose error between the scans of a window smears their arcs: the band points of each block
    # of dbh_align_block_scans scans are moved across their beams onto the window circle (prior
    # sigma dbh_align_sigma_m), then the circle is refitted (dbh_align_iterations times). Blocks,
    # not single scans: a one-scan arc free to move lets a smaller circle fit (every DBH -0.3 to
    # -0.55 cm, also with true poses); within a block the odometry's drift is negligible.
    dbh_align_iterations: Annotated[int, Range(ge=0)] = 2
    dbh_align_block_scans: PositiveInt = 5
    dbh_align_sigma_m: Positive = 0.02
    dbh_max_points_per_window: PositiveInt = 4000  # random subsample beyond this (bounded memory)
    # The per-scan DBH decides when at least this many scans agree within this share of their
    # median (robust spread); else the window circles do (tree_map module docstring).
    dbh_fallback_min_scans: PositiveInt = 3
    dbh_fallback_max_spread: Fraction = 0.15
    # Share of the squared disagreement between the per-scan median and the window circles
    # (an independent measurement of the same DBH) counted in the per-scan median's dbh_std_m:
    # the windows' error is about 3x the median's (bench: map DBH MAE of the windows 1.31 / 2.90
    # / 0.53 cm vs 0.51 / 1.20 / 0.22 cm on vlp16-loop a / b and hdl32-loop a), so about
    # 1 / (1 + 3^2) of it is the median's.
    dbh_disagreement_share: Fraction = 0.1
    # A window DBH above this factor times the median per-scan DBH of its tree (angular
    # widths, independent of the window circle's curvature) is not that stem's circle.
    dbh_max_scan_ratio: Annotated[float, Range(ge=1)] = 1.5
    # A per-scan DBH counts only from scans at ranges where one azimuth step of the sensor
    # spans at most 1 / dbh_resolve_steps of the DBH (TreeMap._resolved_scans): under 2 steps a
    # silhouette comes only from the scans whose steps fell twice on the stem (up to 2x wide).
    dbh_resolve_steps: Annotated[float, Range(ge=1)] = 2.0
    # Stems thinner than dbh_thin_m (1.5 of perception's 5 cm thinning voxels) need
    # dbh_thin_resolve_steps: at 2-3 steps their detection itself depends on whether 2 or 3
    # returns per line fell on them (the normal filter's neighbour count after thinning), and
    # so does their DBH (a 4 cm stem passed at 5 m by a VLP-16: +1.1 cm from 2-3 step scans).
    # At 0.1 a 10.2 cm tree of dbh4 vlp16-loop-b (9.7 cm from its 2-3 step scans) lost its DBH.
    dbh_thin_m: NonNegative = 0.075
    dbh_thin_resolve_steps: Annotated[float, Range(ge=1)] = 3.0
    # Accumulated silhouette (mapping/thin_stems.py) of a tree that has no DBH otherwise (a
    # stem under the single-scan resolution): every scan line crossing its breast-height band
    # +- dbh_sweep_band_m (symmetric: a linear taper averages out) up to dbh_sweep_max_range_m
    # counts its hits: returns within dbh_sweep_window_m across and dbh_sweep_depth_m along
    # the view ray of the stem's centre (the mode of its returns), less the background beside
    # them (as wide again on each side). Window: half the widest stem it measures (dbh_thin_m)
    # plus 3 sigma of the SLAM's per-scan lateral pose noise at 15 m (3.4 cm: consecutive
    # scans' yaw 0.056 deg and 1.2 cm rms against the truth on dbh4 hdl32-loop-b, main): a
    # narrower window loses the hits of scans placed off and, with the background beside it,
    # counts them against the stem (2-3 cm saplings read 0.1-1 cm at 6 cm). Depth: range
    # noise 1.5-3 cm, the pose's 1.2 cm and the stem's own depth. The DBH is reported from
    # dbh_sweep_min_scans scans with crossing lines and dbh_sweep_min_lines lines on, when the
    # hits spread across the stem (the phases cover it: their 10-90 % spread at least
    # dbh_sweep_min_cover of the width), and under dbh_thin_m (wider stems are resolved by the
    # per-scan silhouettes). Its std: the ratio estimator's over blocks of
    # dbh_sweep_block_scans scans or the phase error, with the dbh_std_floor_rel floor.
    # dbh_sweep: count the lines (also for is_empty); dbh_sweep_dbh: report the accumulated
    # DBH. On the 8 DBH loops (two noise draws of one simulated stand): 28 saplings of 2-5 cm
    # measured, mean error -0.33 cm, MAE 0.42 cm, 50 % within 1 sigma, 82 % within 2 (dbh_std_m
    # too narrow); right on true poses (tests/test_dbh_accumulated_silhouette.py). Needs the
    # odometry's motion for the deskew (TreeMap.add_returns T_odom).
    dbh_sweep: bool = True
    dbh_sweep_dbh: bool = True
    # A tree without a DBH with fewer returns than this per crossing line within reach of its
    # centre (TreeMap.is_empty) is left out of the map: a stem of >= 2 cm gives >= 0.23.
    dbh_empty_max_hits: Fraction = 0.1
    dbh_sweep_band_m: tuple[float, float] = (-0.3, 0.3)
    dbh_sweep_window_m: Positive = 0.14
    dbh_sweep_depth_m: Positive = 0.1
    dbh_sweep_max_range_m: Positive = 25.0
    dbh_sweep_min_scans: PositiveInt = 20
    dbh_sweep_min_lines: PositiveInt = 40
    dbh_sweep_min_cover: Fraction = 0.5
    dbh_sweep_block_scans: PositiveInt = 25  # = dbh_window_scans: its centre is found per block
    # ... and only a width at least this many standard errors above 0 (a shrub's or a
    # foliage clump's returns, as dense beside the window as in it, give about 0).
    dbh_sweep_min_sigmas: NonNegative = 3.0
    # ... and only when its hits gather across the view ray (robust spread, 1.4826 MAD): a
    # stem of 3.75 cm radius (dbh_thin_m) under 3.4 cm of lateral pose noise spreads them by
    # about 4.5 cm, a shrub's or foliage returns over the window (+-14 cm) by about 10 cm.
    # Checked on dbh4 hdl32-loop-b: saplings 3.4-4.7 cm (one inside a shrub 6.7), objects
    # matching no stem 6.2-8.9 cm.
    dbh_sweep_max_spread_m: Positive = 0.055
    dbh_sweep_max_scans: PositiveInt = 4096  # per tree (bounded memory)
    # Trees written to the map need this many keyframe observations.
    min_tree_observations: PositiveInt = 3
    # Ground map (map3d mode): per-keyframe ground points kept at keyframe_voxel_m, the
    # global map rebuilt from the optimised keyframe poses at voxel_m; DTM cells of dtm_cell_m.
    ground_keyframe_voxel_m: Positive = 0.2
    ground_voxel_m: Positive = 0.2
    dtm_cell_m: Positive = 0.5
    dtm_min_points: PositiveInt = 2
    # DTM cells more than dtm_max_raise_m above the grey opening over dtm_window_m (objects
    # narrower than the window: shrubs, logs) are removed; dtm_window_m <= 0 keeps every cell.
    dtm_window_m: float = 5.0
    dtm_max_raise_m: NonNegative = 0.3
    # map3d: scan-to-map point-to-plane ICP refinement of keyframes on stem + ground points.
    refine_with_icp: bool = True
    icp_local_map_keyframes: PositiveInt = 10
    icp_voxel_m: Positive = 0.1
    icp_max_correction_m: Positive = 0.5  # a larger ICP correction is rejected as a failure
    icp_sigma_floor_m: Positive = 0.02
    icp_sigma_floor_deg: Positive = 0.2
    # Outputs: trajectory / trees rewritten atomically every this many scans.
    checkpoint_every_scans: PositiveInt = 100
    # map.laz (slam, map3d): every keyframe's scan thinned to map_voxel_m, ground and tree ids.
    map_laz: bool = True
    map_voxel_m: Positive = 0.1
