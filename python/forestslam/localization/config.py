"""Configuration of global localization against a prior tree map (Li et al. triangle stars)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal

from forestslam.config_utils import (
    Fraction,
    NonNegative,
    NonNegativeInt,
    Positive,
    PositiveInt,
    Range,
)

MATCHERS = ("default", "paper")  # the choices of `matcher`


@dataclass
class LocalizationConfig:
    """Star matching, verification and acceptance of a query; aggregation of frames (CLI)."""

    # Keys earlier versions wrote into run.yaml (key -> why it is no longer read).
    RETIRED_KEYS: ClassVar[dict[str, str]] = {
        "dbh_resolution_m": "the DBH evidence is a likelihood ratio now; see dbh_sigma_m",
    }

    # "default": stars verified by edge lengths and the side test, a pose per match, consensus;
    # "paper": Li et al. as written (Eq. 2-4, no peripheral stars, t_h = 2 m in trunk
    # extraction). Both end in the same refinement and acceptance test.
    matcher: Literal["default", "paper"] = "default"

    candidates_per_star: PositiveInt = 8  # k nearest map stars per local star
    max_feature_distance_m: Positive = 1.5  # in the sqrt feature space (sqrt area, perimeter)
    rotation_ambiguity: NonNegative = 0.15  # try other start edges up to this much longer
    edge_tolerance_m: Positive = 0.35  # edge-length agreement of corresponding triangles
    inlier_gate_m: Positive = 0.5  # local trunk this close to a map trunk counts as consensus
    min_inliers: Annotated[int, Range(ge=3)] = 4  # fewer: rejected (the significance test decides)
    # The floor when every inlier has a DBH on both sides (a triangle's shape and 3 DBH
    # agreements can be significant; the test decides).
    min_inliers_with_dbh: Annotated[int, Range(ge=3)] = 3
    min_inlier_fraction: Fraction = 0.25  # of the local trunks; fewer: rejected
    # rejected when the second-best distinct pose scores this much
    ambiguity_ratio: NonNegative = 0.8
    # Calibrated acceptance: -log10 of the probability that the inliers arise by chance at the
    # map's local trunk density (Poisson tail, corrected for the hypotheses searched): 2.3 is a
    # chance probability of 0.005, the target rate of accepted absent places (the test is
    # conservative: measured rates are lower, see bench/localize_bench.py).
    min_significance: NonNegative = 2.3
    # Test how close the inliers land as well as how many (truncated product: a true pose puts
    # them within the positioning noise, chance ones anywhere in the gate); residuals below
    # min_sigma_m count as min_sigma_m.
    closeness_evidence: bool = True
    # Test how closely the seed shape (a star's 9 edges, a triangle's 3 sides) matches its map
    # shape too: a chance match lies anywhere within edge_tolerance_m, a true one within the
    # noise; edge differences below 2 min_sigma_m count as 2 min_sigma_m.
    seed_evidence: bool = True
    # When the map and the query both carry stem diameters (localize(..., local_dbh_m=)): weigh
    # each inlier's DBH by its likelihood ratio, a match (difference ~ N(0, dbh_sigma_m): query
    # and map errors) against the DBHs of the map trunk's 30 neighbours, with a share
    # dbh_outlier_fraction of gross errors. Calibrated whatever the stand (its mean under a
    # chance pose is 1); a wrong sigma only costs power, a gross DBH at most ln(1 / fraction).
    dbh_evidence: bool = True
    dbh_sigma_m: Positive = 0.03
    dbh_outlier_fraction: Fraction = 0.1
    distinct_translation_m: NonNegative = 1.0  # poses further apart than this are distinct
    distinct_yaw_deg: NonNegative = 5.0
    refine_iterations: NonNegativeInt = 5  # least-squares refinement rounds over all inliers
    min_sigma_m: Positive = 0.02  # floor of the residual sigma used for the covariance
    duplicate_tolerance_m: NonNegative = 0.01  # local trunks closer than this are one trunk
    skip_hull_stars: bool = False  # drop local stars touching the local convex hull
    # Single-triangle matching when no star hypothesis is accepted; its answers are marked
    # stage "triangle" and held to the same significance test.
    triangle_fallback: bool = True
    # k nearest map triangles per local triangle (fallback)
    candidates_per_triangle: PositiveInt = 16
    # fallback triangles: each local trunk with 2 of its k nearest
    triangle_neighbours: Annotated[int, Range(ge=2)] = 5
    # hypotheses scored on this many trunks nearest the origin
    max_query_trunks: Annotated[int, Range(ge=3)] = 100
    # fallback triangles only from this many nearest trunks
    max_fallback_trunks: Annotated[int, Range(ge=3)] = 40
    # verified fallback triangle matches at most (time bound)
    max_fallback_matches: PositiveInt = 500
    # Aggregation of several scans into one query (CLI / aggregate_stems).
    merge_radius_m: NonNegative = 0.3  # detections of one trunk from several frames are merged
    # frames of a query this far apart; 0 = consecutive scans
    keyframe_distance_m: NonNegative = 0.0
    min_observations: PositiveInt = 1  # with >= 3 frames, trunks seen fewer times are dropped
    # Sequence input (`forestslam localize BAG`): a rejected query is retried once on up to this
    # many of the last frames, aggregated by odometry (the trunks already driven past; a view
    # of at most 3 map trunks is always rejected). 0 or at most the query's frames: off.
    retry_frames: NonNegativeInt = 5
    # Still rejected on retry_frames: once more on up to this many (the machine keeps driving:
    # 7 frames 3 m apart span 18 m); at most retry_frames: off. Every look of a query that may be
    # retried is tested at chain_significance(min_significance, looks), so the chance that ANY
    # look accepts an absent place stays within the level.
    retry_last_frames: NonNegativeInt = 7
    retry_keyframe_distance_m: NonNegative = 3.0  # the retry's frames at least this far apart
    max_range_m: Positive = 25.0  # detections further from their sensor are dropped

    @property
    def trunk_height_offset_m(self) -> float:
        """t_h of trunk extraction from map clouds: the paper's 2 m in paper mode."""
        return 2.0 if self.matcher == "paper" else 1.0
