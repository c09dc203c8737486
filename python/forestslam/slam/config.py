"""Configuration of the landmark SLAM back end (GTSAM iSAM2, Pose2 + Point2 trees)."""

from __future__ import annotations

from dataclasses import dataclass
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
class SlamConfig:
    # Keyframes: factors are added and iSAM2 updated only at keyframes (keeps it real time).
    # 1 m was measured (issue 18): -0.3 to -0.6 ms per scan, but with the coarse ICP stride the
    # RPE was higher on 8 of 9 sequences (within the run-to-run spread) and fewer keyframes
    # break the multisession duplicates test's closure; kept at 0.5.
    keyframe_distance_m: NonNegative = 0.5
    keyframe_yaw_deg: NonNegative = 10.0
    keyframe_max_interval_s: Positive = 1.0
    # Odometry factor noise: the registration covariance, summed between keyframes, floored
    # (a constant plus a part proportional to the distance travelled) and inflated when degraded.
    odom_floor_xy_m: Positive = 0.01
    odom_floor_yaw_deg: Positive = 0.2
    odom_floor_per_m: NonNegative = 0.01  # extra sigma (m, and rad for yaw) per metre travelled
    degraded_inflation: Annotated[float, Range(ge=1)] = 10.0
    odom_max_sigma_step: Positive = 0.5  # eigenvalue caps (m / rad) of a step's covariance
    odom_max_sigma_keyframe: Positive = 2.0  # ... and of a keyframe factor's covariance
    # Tree observations (range-bearing): the stem centre's position noise, converted to a
    # bearing sigma by the range; observations beyond max range are ignored.
    observation_sigma_m: Positive = 0.08
    bearing_floor_deg: Positive = 0.3
    max_observation_range_m: Positive = 20.0
    min_observation_range_m: NonNegative = 0.5
    # Online estimate of a radial offset common to all stem centres (0 gain: off): the share of
    # the median range residual of trees seen >= min observations applied at each keyframe.
    range_offset_gain: Annotated[float, Range(ge=0, le=1)] = 0.2
    range_offset_min_observations: PositiveInt = 6
    robust_kernel: Literal["huber", "cauchy", "none"] = "huber"  # huber | cauchy | none
    robust_k: Positive = 1.345
    # Data association: a consensus shift (drift since the trees were mapped) found within
    # the search radius, then one-to-one assignment by Mahalanobis distance (chi2 gate, 2 dof).
    association_chi2: Positive = 9.21
    search_radius_min_m: Positive = 0.6
    search_radius_max_m: Positive = 3.0
    consensus_inlier_m: Positive = 0.35
    consensus_min_support: PositiveInt = 3
    landmark_sigma_floor_m: Positive = 0.03
    # |dbh_obs - dbh_map| <= ratio * dbh_map + 5 cm when both known
    dbh_gate_ratio: NonNegative = 0.5
    min_landmark_separation_m: NonNegative = 0.7
    # Tentative landmarks enter the graph after this many observations within this gate.
    tentative_min_observations: PositiveInt = 3
    tentative_gate_m: Positive = 0.5
    tentative_max_age_keyframes: PositiveInt = 8
    # Scans between keyframes are aligned onto the tree map when this many stems match (0: off).
    scan_align_min_matches: NonNegativeInt = 4
    # Height correction: per-keyframe z offsets and tree centre heights in a linear 1D graph
    # (the planar graph leaves z to the odometry, which drifts on rough ground). Sigmas: a tree
    # centre's height observation; the z random walk between keyframes, plus per metre.
    # Off by default (issue 18): on the simulator's VLP-16 sequences it made z worse, also on
    # rough ground (vlp16-rough, 1,200 scans: z RMSE 0.022 m odometry, 0.035 m corrected).
    height_correction: bool = False
    height_obs_sigma_m: Positive = 0.1  # perception centre heights: ~6 cm MAD on rough ground
    height_step_sigma_m: Positive = 0.005
    height_sigma_per_m: NonNegative = 0.01
    # Tracking loss (multi-session, issue 21): at a keyframe, when at least `loss_min_tracked`
    # trees seen at the previous keyframe are still in range but at most `loss_max_refound` of
    # them are re-found, the odometry jumped: its factor across the loss gets `loss_sigma_m` /
    # `loss_sigma_deg` (a new, nearly free segment) and, until place recognition relocalizes the
    # segment, trees are associated only with the segment's own (0: never break the chain).
    loss_min_tracked: NonNegativeInt = 6
    loss_max_refound: Fraction = 0.25
    loss_sigma_m: Positive = 10.0
    loss_sigma_deg: Positive = 90.0
    # iSAM2
    relinearize_threshold: NonNegative = 0.01
    # GTSAM's default: the relinearization check every 10th update (big corrections force one,
    # see extra_updates_on_loop); 1 cost 20-30 % more back-end CPU for the same ATE (issue 18).
    relinearize_skip: PositiveInt = 10
    # extra iSAM2 iterations, relinearizing, when a big correction arrives
    extra_updates_on_loop: NonNegativeInt = 2
    loop_correction_m: NonNegative = 0.3
