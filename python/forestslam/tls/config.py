"""Configuration of MLS-to-TLS plot mapping (Shao et al. 2020)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from forestslam.config_utils import (
    Fraction,
    NonNegative,
    NonNegativeInt,
    Positive,
    PositiveInt,
    Range,
)


@dataclass
class FeatureConfig:
    """Per-frame features: DoG keypoints (real) and ring stem centres (virtual)."""

    max_keypoints: PositiveInt = 200
    keypoint_voxel_m: Positive = 0.08
    sigma_small_m: Positive = 0.15
    sigma_large_m: Positive = 0.30
    nms_radius_m: NonNegative = 0.6
    min_diameter_m: Positive = 0.06
    max_diameter_m: Positive = 1.0
    # Ground samples (real features, see features.ground_samples): lowest point per cell.
    ground_max_points: NonNegativeInt = 120
    ground_cell_m: Positive = 1.0
    ground_max_range_m: Positive = 15.0
    ground_max_step_m: NonNegative = 0.3
    ground_band_m: NonNegative = 0.1


@dataclass
class MapConfig:
    """Global incremental map: TLS reference plus accepted MLS frames, voxelized."""

    voxel_m: Positive = 0.03
    # A frame joins the map when its stem-centre (virtual) residual RMS is below this and it
    # has enough virtual pairs; frames without stems still get a pose but never join the map.
    # Polygonal, oval stems (bench/tls_bench.py --style b) give correctly placed frames 1.2-4.5
    # cm RMS, so this gate drops many good frames there (longleaf-lawn-20m-b: 95.3 % tracked).
    # A gate learnt from the walk's trusted frames (median + 3 x 1.4826 MAD, this as floor) was
    # measured on both styles' 150-frame tables and not kept: longleaf-b tracking 95.3 -> 98.7
    # and 96.7 -> 98.0 %, but the extra frames carry larger pose errors (merged frames > 3 cm
    # off 3 -> 7, 19 -> 27) and style a lost targets (longleaf-loop-12m stem 1.21 -> 1.63 cm,
    # longleaf-lawn-20m DBH 1.28 -> 1.59 cm), spruce-line-far-b tracking 99.3 -> 96.7 %.
    accept_virtual_rms_m: Positive = 0.03
    accept_min_virtual_inliers: NonNegativeInt = 24
    # ... and when it also sits on the TLS reference itself, not only on the growing map (which
    # may hold frames with small errors): the LM of the frame against the reference alone,
    # started at the frame's pose with the fine gates, must converge, not be degenerate and
    # move the pose by at most accept_reference_max_m / accept_reference_max_deg. A frame
    # placed on wrongly merged frames, or in a wrong local minimum, moves (or fails) there.
    accept_reference_max_m: NonNegative = 0.03
    accept_reference_max_deg: NonNegative = 0.3
    accept_reference_rounds: PositiveInt = 4
    frame_min_range_m: NonNegative = 1.0  # the operator carrying the scanner is not mapped
    frame_max_range_m: Positive = 25.0
    # Points of an accepted frame join the map only up to this range (the frame registers on
    # all up to frame_max_range_m): an angular pose error d moves a point at range r by r*d.
    # 12 m on spruce-lawn-3m: whole walk tracked 98.0 -> 99.5 %, merged map stems 39 -> 67 of
    # 103; but 150 frames: stems 119 -> 108 true, coverage 56 -> 44 %. Default: no cap.
    merge_max_range_m: Positive = 25.0
    # Accepted frames are merged into the map (and the LM target rebuilt) in batches of this
    # many frames (cost bounded; a frame is registered against the map as of the last batch).
    rebuild_every_frames: PositiveInt = 30
    # LM target: a voxelized copy of the map cropped around the predicted pose (x-y disc,
    # height band of the frame plus target_z_margin_m), so its size does not grow with the
    # reference; re-cropped when the platform has moved target_recrop_m from the crop
    # centre, the frame leaves the height band, or the map has changed. The radius should
    # cover the frame's useful range (frame_max_range_m) plus the re-crop distance.
    target_voxel_m: Positive = 0.05
    # lm_target "map": the whole merged map (the reference and every merged frame, each voxel
    # their running mean). "confirmed": the reference's voxels and, of the merged frames'
    # voxels (same size), only those no reference voxel touches (within this many voxels: the
    # merged frames' copies of surfaces the reference holds only thicken its walls) that at
    # least target_min_merges merge batches filled (not one batch's noise or error); it does
    # not grow with every merge. On the 14-cell bench (150 frames) "confirmed" cut the LM
    # 10-42 % per frame and the merged frames' pose error on 12 cells (e.g. spruce-lawn-3m
    # 1.09 -> 0.70 cm). With the old, point-order-dependent DBH stage the frames it merges
    # redrew which far stems got a DBH (clustered-loop-8m 1.05 -> 1.63 cm), so it was off;
    # with the order-free stage (trees.canonical_order, trees.arc_sigma) and rescue_in_sweep,
    # every cell's stem and DBH error is <= 1.3 cm and 13 of 14 cells track >= 98 %
    # (longleaf-lawn-20m 99.3 -> 96.7 %, the one cell worse). Whole spruce-lawn-3m walk
    # (1,320 frames, both on): 6.9 -> 9.5 frames per CPU s, tracked 98.6 -> 100 %, merged
    # 933 -> 1153 frames, merged-frame pose error 2.08 -> 1.19 cm, stem 0.87 -> 0.70 cm, DBH
    # 1.18 -> 0.98 cm.
    lm_target: Literal["confirmed", "map"] = "confirmed"
    target_reference_margin_voxels: NonNegativeInt = 1
    target_min_merges: PositiveInt = 2
    target_radius_m: Positive = 30.0
    target_recrop_m: NonNegative = 5.0
    target_z_margin_m: NonNegative = 1.5
    max_points: PositiveInt = 30_000_000


@dataclass
class RegistrationConfig:
    ndt_voxel_m: Positive = 0.3
    ndt_resolution_m: Positive = 1.0
    lm_virtual_gate_m: Positive = 0.1
    lm_plane_gate_m: Positive = 0.25
    lm_robust_scale_m: Positive = 0.05
    lm_max_rounds: PositiveInt = 15
    # Initial pose of each frame: "ndt" = 3D-NDT against the previous frame (the motion
    # model's prediction as its guess) chained onto that frame's pose (the paper);
    # "velocity" = the motion model's constant-velocity prediction (the odometry's
    # forestslam::odometry::ConstantVelocityModel), NDT only as a fallback when the LM from
    # the prediction is not trusted (~26 ms CPU less per VLP-16 frame).
    initial_pose: Literal["ndt", "velocity"] = "ndt"
    # Spinning scans with per-point time are deskewed (constant velocity from the last two
    # frames) to the middle of their sweep and registered there.
    deskew: bool = True
    # ... and, once registered rigidly, registered again with the motion during the sweep
    # estimated as a polynomial of this order in time (0: rigid frames; see tls.sweep), with
    # sweep_lm_rounds correspondence rounds; kept when that LM is trusted. Needs per-point time.
    # Its 6 (order + 1) unknowns take more rounds to converge than the rigid LM: at 10 rounds
    # 36 of 150 frames of the 1.5 deg vibrating walk (bench/tls_bench.py --plots, spruce-line-
    # far) did not converge (kept rigid, never merged), at 25 rounds 8 (+8 % CPU).
    sweep_order: NonNegativeInt = 2
    sweep_lm_rounds: PositiveInt = 25
    # A frame whose rigid LM ran out of rounds near its minimum (not degenerate, residual and
    # correction within the gates) registered with its in-sweep motion from there, trusted
    # only if that converges (pipeline._rescue_in_sweep). On the 14-cell bench it tracks
    # longleaf-lawn-20m-b 96.0 -> 98.7 % (a vibrating sensor: the rigid LM creeps and runs
    # out of rounds); with lm_target "map" it moved clustered-loop-8m-b's DBH RMSE 1.50 ->
    # 1.53 cm, with "confirmed" (the default) 1.28 cm.
    rescue_in_sweep: bool = True
    lm_converged_translation_m: NonNegative = 1e-3  # a round moving less than this ends the LM ...
    lm_converged_rotation_rad: NonNegative = 2e-4  # ... when it also rotates less than this
    # A frame's pose is trusted (chained from, and may join the map) when the LM converged,
    # is not degenerate, its real-feature residual RMS is below good_real_rms_m and it moved
    # the predicted pose (constant velocity) by at most max_correction_m / max_correction_deg.
    # Otherwise NDT against the previous frame chained onto its pose gives a second initial
    # pose (fallback); when that fails too the frame is rejected (not merged, velocity not
    # updated) and keeps the NDT-chained (else predicted) pose.
    good_real_rms_m: Positive = 0.12
    # A frame that does not join the map (its pose not verified) between two merged frames at
    # most this far apart in time keeps its own orientation and takes its position from them,
    # linear in time (tls.bridging; 0: off). A walk's position changes smoothly over half a
    # second (5 frames of a 10 Hz scanner), its orientation not (vibration).
    bridge_max_gap_s: NonNegative = 0.5
    max_correction_m: Positive = 1.5
    max_correction_deg: Positive = 15.0
    # Coarse alignment by stem positions (pairwise-spacing vote: placement hypotheses, see
    # InitConfig, and relocalization).
    coarse_distance_tolerance_m: Positive = 0.25
    coarse_inlier_m: Positive = 0.35
    coarse_min_stems: Annotated[int, Range(ge=2)] = 3
    # After this many consecutive frames that did not join the map the tracking counts as
    # lost and each frame is also placed afresh by the coarse stem alignment (then LM; kept
    # when trusted with its stems on the reference's stems).
    relocalize_after_frames: PositiveInt = 3
    # The velocity (deskew, NDT guess, prediction) is only used while it is fresh: measured
    # between two consecutive trusted frames at most this long ago. A stale velocity (e.g. the
    # turn rate at the moment tracking was lost) would keep distorting every later frame by
    # its deskew and send the prediction around in circles, so tracking could never recover.
    max_velocity_age_s: Positive = 0.5


@dataclass
class InitConfig:
    """Placing the walk without --initial-pose (see tls.initialize): the frames before the
    placement are chained by NDT into a local stem map; hypotheses from stem constellations
    are verified by the LM and by stem consensus; frames are tried until one is placed."""

    min_frames: PositiveInt = 3  # frames accumulated before the first placement attempt
    window_frames: PositiveInt = (
        30  # the local stem map holds the stems of at most this many frames
    )
    merge_radius_m: NonNegative = 0.3  # detections of one stem from several frames are merged
    min_local_stems: Annotated[int, Range(ge=3)] = (
        4  # a placement is attempted when the local map holds this many
    )
    hypotheses: PositiveInt = (
        4  # pairwise-vote hypotheses verified per attempt (plus the localizer's)
    )
    # Verification: local stems moved by the LM-refined pose onto a reference stem within
    # consensus_gate_m and consensus_radius_m of its radius; the placement needs at least
    # min_consensus_stems of them and min_consensus_fraction of the local stems that lie
    # inside the hull of the reference's stems (outside it none is expected), and no
    # distinct verified placement with ambiguity_ratio as many.
    consensus_gate_m: Positive = 0.1
    consensus_radius_m: Positive = 0.05
    min_consensus_stems: PositiveInt = 5
    min_consensus_fraction: Fraction = 0.4
    ambiguity_ratio: Fraction = 0.7
    # The frames before the placed one are chained back through the odometry; the LM refines
    # a frame when trusted from the chained pose (the tracking's gates, max_correction_*) and
    # its stems then sit on the reference's stems (the merge's gross-error test); else the
    # chained pose stands. Such frames are never merged.


@dataclass
class TreeConfig:
    """Stems and DBH of the merged cloud; stem coverage at breast height."""

    band_m: tuple[NonNegative, Positive] = (1.2, 1.4)
    ground_cell_m: Positive = 1.0
    coverage_sectors: PositiveInt = 36
    coverage_tolerance_m: Positive = 0.03
    # Stem detection in the cloud (layer circle fits, see features.reference_stems): inlier
    # threshold and largest fit RMS. A plot map merged from mobile frames has stem walls as
    # thick as the mobile scanner's range noise (VLP-16: 1.5 cm sigma) plus the registration
    # spread, so the single-scan gates (1.5 cm) drop most of its stems; 2x the sensor noise.
    stem_fit_inlier_m: Positive = 0.03
    stem_max_fit_rms_m: Positive = 0.03
    # A stem's DBH is reported only when the points of the map and the reference cover this
    # share of its breast-height circumference (trees.report_dbh; else NaN, position kept):
    # on a shorter arc the radius is not determined by the points.
    min_dbh_coverage: Fraction = 0.25
    # ... and only when its fit resolves the diameter: the 1-sigma of the fitted diameter, both
    # from the fit's own covariance (residual spread, point count, arc geometry) and from the
    # spread of four independent sub-slice fits (trees.diameter_resolved), at most this DBH
    # precision (the stated target, Shao et al.'s 1.5 cm DBH RMSE). A larger sigma means the
    # points allow circles that differ by more than the figure reported.
    # A diameter within this precision of the smallest fitted (features.min_diameter_m) is
    # held by that bound, not by the points: no DBH either.
    max_dbh_sigma_m: Positive = 0.015
    # The third estimate of that 1-sigma (trees.arc_sigma): a block jackknife over this many
    # runs of the circle's inliers by angle, i.e. how much the diameter depends on which part
    # of the arc is seen (a stem's shape bends its arc; the covariance takes that for noise).
    dbh_arc_blocks: PositiveInt = 6
    # A stem's points are a face seen from outside: every point faces a scanner that saw it
    # (its outward normal from the circle's centre points towards the scanner). A circle
    # fitted on a noise blob can bend the other way, its centre on the scanners' side of the
    # points (a 24 cm stem 27.6 m out fitted 10 cm; a 14.5 cm stem 31.8 m out fitted 28 cm,
    # 23 cm off). A circle whose inliers face a scanner less often than this share gives its
    # stem no DBH and no measured position (trees.faced_share).
    min_faced_share: Fraction = 0.75
    # Where the reference was scanned from, in its own frame (x, y), for the face test
    # (trees.reference_scanners). "auto": the scanner position the file gives (a PCD
    # VIEWPOINT other than PCL's default 0 0 0), else the origin of the reference's frame when
    # it lies inside the reference's xy extent (a single TLS scan is stored in its scanner's
    # frame and surrounds it), else not known (a georeferenced cloud, e.g. UTM, lies far from
    # its origin); either kept only when the reference's stem points face it (below). A list:
    # these positions (a registered multi-scan plot: its stations).
    # Empty, or auto finding none: not known; then only the mobile walk's positions are
    # scanners for the face test (a stem whose back only the reference saw then fails it: it
    # loses its DBH, it is not given a wrong one). The choice is logged and in run.yaml.
    reference_scanners_xy: Literal["auto"] | tuple[tuple[float, float], ...] = "auto"
    # auto keeps a position (viewpoint or origin) only when at least this share of the
    # reference's points on the stems' breast-height circles face it (trees.reference_faced_
    # share). Measured: the single scans of 4 bench plots 99.7-99.8 % (their station), 48-84 %
    # (a station 10 m off); the tests' world 96.0 % (it models half of each stem as seen, a
    # little more than a scanner sees); a two-station synthetic plot 61 %; the real TreeLS
    # pine plot (several scans), recentred, 37 %.
    min_reference_faced_share: Fraction = 0.9
    # A stem's position (breast-height circle centre) counts as measured when its circle
    # passes the face test and the 1-sigma of its centre (the largest from the fit's
    # covariance) is at most this (the stated target, Shao et al.'s stem position error). The
    # position is always reported; trees.csv and the bench say which are measured.
    max_position_sigma_m: Positive = 0.015


@dataclass
class TlsConfig:
    features: FeatureConfig = field(default_factory=FeatureConfig)
    map: MapConfig = field(default_factory=MapConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    init: InitConfig = field(default_factory=InitConfig)
    trees: TreeConfig = field(default_factory=TreeConfig)
    frame_step: PositiveInt = 1  # process every n-th MLS frame
    # tls-register rewrites run.yaml and trajectory.tum (the frames registered so far) every
    # this many frames, so a killed run leaves valid files up to its last checkpoint.
    checkpoint_every_frames: PositiveInt = 20
