"""Global localization facade: local trunks -> pose of the local frame in a prior tree map."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from forestslam.core_bridge import fill_core
from forestslam.errors import InputError
from forestslam.geometry import planar_pose
from forestslam.localization.config import LocalizationConfig
from forestslam.localization.tree_map import TreeMap

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunnerUp:
    """The best hypothesis distinct from the answer (scored on the same trunks)."""

    x: float = math.nan
    y: float = math.nan
    yaw: float = math.nan
    inliers: int = 0
    significance: float = 0.0  # same test as the answer's (-log10 chance probability)

    @property
    def exists(self) -> bool:
        return math.isfinite(self.x)


@dataclass
class Localization:
    """Pose of the local frame in the map frame: ``map = R(yaw) @ local + (x, y)``."""

    x: float
    y: float
    yaw: float  # radians
    covariance: np.ndarray  # (3,3) over x, y, yaw
    inliers: int
    rejected: bool
    reason: str = ""  # why it was rejected ("" when accepted)
    second_inliers: int = 0  # consensus of the best distinct alternative pose
    stage: str = ""  # matcher of the answer: "star", "triangle" (fallback) or "" (none)
    # -log10 of the probability that the inliers arise by chance at the map's local trunk
    # density, corrected for the hypotheses searched; accepted only >= min_significance.
    significance: float = 0.0
    expected_chance_inliers: float = 0.0
    dbh_pairs: int = 0  # inliers with a DBH on both sides (0: no DBH evidence)
    runner_up: RunnerUp = field(default_factory=RunnerUp)
    hypotheses: int = 0
    matched_triangles: int = 0  # star matches agreeing with the answer (Li et al.'s count)
    local_trunks: int = 0
    rms_m: float = 0.0
    matches: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int32))
    time_ms: float = 0.0

    @property
    def accepted(self) -> bool:
        return not self.rejected

    def matrix(self) -> np.ndarray:
        """(4,4) T_map_local (planar: z, roll and pitch zero)."""
        return planar_pose(self.x, self.y, self.yaw)

    def to_dict(self) -> dict:
        return {
            "accepted": self.accepted,
            "x": self.x,
            "y": self.y,
            "yaw": self.yaw,
            "inliers": self.inliers,
            "second_inliers": self.second_inliers,
            "stage": self.stage,
            "significance": self.significance,
            "expected_chance_inliers": self.expected_chance_inliers,
            "dbh_pairs": self.dbh_pairs,
            "runner_up": {
                "x": self.runner_up.x if self.runner_up.exists else None,
                "y": self.runner_up.y if self.runner_up.exists else None,
                "yaw": self.runner_up.yaw if self.runner_up.exists else None,
                "inliers": self.runner_up.inliers,
                "significance": self.runner_up.significance,
            },
            "local_trunks": self.local_trunks,
            "rms_m": self.rms_m,
            "reason": self.reason,
            "covariance": np.asarray(self.covariance).tolist(),
        }


# Options of the trunk aggregation (not of the C++ matcher), and two that need converting.
_NOT_IN_CORE = (
    "merge_radius_m",
    "keyframe_distance_m",
    "min_observations",
    "max_range_m",
    "distinct_yaw_deg",
    "matcher",
    "retry_frames",
    "retry_last_frames",
    "retry_keyframe_distance_m",
)


def _core_config(config: LocalizationConfig):
    """The C++ localizer's config, through the one bridge (a missing option is an error)."""
    from forestslam import _core

    c = fill_core(config, _core.GlobalLocalizerConfig(), "localization", skip=_NOT_IN_CORE)
    c.distinct_yaw_rad = math.radians(config.distinct_yaw_deg)
    c.matcher = getattr(_core.Matcher, config.matcher)
    return c


def _runner_up(r) -> RunnerUp:
    if r is None or not r.exists:
        return RunnerUp()
    return RunnerUp(r.x, r.y, r.yaw, r.inliers, r.significance)


def chain_significance(min_significance: float, looks: int) -> float:
    """The significance each of ``looks`` tests of one place must reach so that the chance that
    ANY of them accepts an absent place stays at 10**-min_significance (Bonferroni: the looks
    of a query retried on more frames share most trunks, so this is conservative)."""
    if looks < 1:
        raise ValueError(f"looks must be >= 1 (got {looks})")
    return min_significance + math.log10(looks)


def localize(
    tree_map: TreeMap,
    local_xy: np.ndarray,
    config: LocalizationConfig | None = None,
    local_dbh_m: np.ndarray | None = None,
    observations: np.ndarray | None = None,
) -> Localization:
    """Pose of the frame of ``local_xy`` (K,2) trunk positions in ``tree_map``'s frame.

    ``local_dbh_m`` (K,) the trunks' diameters in metres (NaN where unknown): when the map has
    DBH too, their agreement is evidence of the acceptance test (``config.dbh_evidence``).
    ``observations`` (K,) in how many aggregated frames each trunk was detected
    (``aggregate_stems(..., return_observations=True)``): the single-triangle stage tries
    triangles of trunks seen in 2 or more frames first (a transient false detection is seen in
    one); the acceptance test does not use them. None: all trunks alike.
    Never raises for few, collinear, duplicate or NaN trunks: the result is ``rejected`` with a
    ``reason``. A ``(K,2)`` shape is required, and one DBH and count per trunk (InputError
    otherwise).
    """
    import time

    config = config or LocalizationConfig()
    local = np.asarray(local_xy, dtype=np.float64)
    if local.ndim != 2 or (local.shape[1] != 2 and len(local) > 0):
        raise InputError(f"localize: local trunks must have shape (K,2), got {local.shape}")
    local = np.ascontiguousarray(local.reshape(-1, 2))
    dbh = np.zeros(0) if local_dbh_m is None else np.asarray(local_dbh_m, dtype=np.float64)
    if local_dbh_m is not None and dbh.shape != (len(local),):
        raise InputError(
            f"localize: local_dbh_m must have one value per trunk ({len(local)},), got {dbh.shape}"
        )
    seen = np.zeros(0, np.int32) if observations is None else np.asarray(observations)
    if observations is not None and seen.shape != (len(local),):
        raise InputError(
            f"localize: observations must have one count per trunk ({len(local)},), "
            f"got {seen.shape}"
        )
    core_config = _core_config(config)
    t0 = time.perf_counter()
    r = tree_map.index.localize(
        local, core_config, np.ascontiguousarray(dbh), np.ascontiguousarray(seen, dtype=np.int32)
    )
    ms = 1e3 * (time.perf_counter() - t0)
    result = Localization(
        x=r.x,
        y=r.y,
        yaw=r.yaw,
        covariance=np.array(r.covariance),
        inliers=r.inliers,
        rejected=r.rejected,
        reason=r.reason,
        second_inliers=r.second_inliers,
        stage=getattr(r, "stage", ""),
        significance=getattr(r, "significance", 0.0),
        expected_chance_inliers=getattr(r, "expected_chance_inliers", 0.0),
        dbh_pairs=r.dbh_pairs,
        runner_up=_runner_up(getattr(r, "runner_up", None)),
        hypotheses=r.hypotheses,
        matched_triangles=getattr(r, "matched_triangles", 0),
        local_trunks=r.local_trunks,
        rms_m=r.rms_m,
        matches=np.array(r.matches),
        time_ms=ms,
    )
    log.debug(
        "localize: %d trunks -> %s (%s, %d inliers, significance %.1f, second %d, "
        "%d hypotheses, %.2f ms)",
        r.local_trunks,
        "rejected: " + r.reason if r.rejected else "accepted",
        result.stage or "-",
        r.inliers,
        result.significance,
        r.second_inliers,
        r.hypotheses,
        ms,
    )
    return result


def aggregate_stems(
    xys: list[np.ndarray],
    poses: list[np.ndarray],
    config: LocalizationConfig | None = None,
    return_observations: bool = False,
):
    """Trunks seen in several scans, in the frame of the last scan.

    ``xys[i]`` (K_i,2) stem centres in scan i's sensor frame, ``poses[i]`` (4,4)
    T_world_sensor of scan i (odometry). Detections beyond ``max_range_m`` are dropped,
    detections of one trunk from several scans (closer than ``merge_radius_m``) are averaged,
    and with at least 3 scans a trunk must be seen in ``min_observations`` of them (transient
    false detections do not repeat). Returns (K,2) in the last scan's sensor frame (planar);
    with ``return_observations`` also (K,) int, the scans each trunk was seen in (for
    ``localize(..., observations=)``).
    """
    config = config or LocalizationConfig()
    if len(xys) != len(poses):
        raise InputError(f"aggregate_stems: {len(xys)} stem sets for {len(poses)} poses")
    empty = (np.zeros((0, 2)), np.zeros(0, dtype=np.int32))
    if not xys:
        return empty if return_observations else empty[0]
    T_last_world = np.linalg.inv(np.asarray(poses[-1], dtype=np.float64))
    parts, frame_ids = [], []
    for k, (xy, pose) in enumerate(zip(xys, poses, strict=True)):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        xy = xy[np.isfinite(xy).all(axis=1)]
        xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= config.max_range_m]
        if len(xy) == 0:
            continue
        T = T_last_world @ np.asarray(pose, dtype=np.float64)
        pts = np.column_stack([xy, np.zeros(len(xy)), np.ones(len(xy))])
        parts.append((pts @ T.T)[:, :2])
        frame_ids.append(np.full(len(xy), k))
    if not parts:
        return empty if return_observations else empty[0]
    points = np.concatenate(parts)
    centres, labels = merge_close(points, config.merge_radius_m, return_labels=True)
    seen = np.zeros((len(centres), len(xys)), dtype=bool)
    seen[labels, np.concatenate(frame_ids)] = True
    counts = seen.sum(axis=1).astype(np.int32)
    if len(xys) >= 3 and config.min_observations > 1:
        keep = counts >= config.min_observations
        centres, counts = centres[keep], counts[keep]
    return (centres, counts) if return_observations else centres


def merge_close(xy: np.ndarray, radius: float, return_labels: bool = False):
    """Average points into clusters whose members are chained closer than ``radius``.
    Returns the (C,2) centres, and with ``return_labels`` the cluster of every point too."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = len(xy)
    if n < 2 or radius <= 0:
        labels = np.arange(n)
        return (xy, labels) if return_labels else xy
    pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    k, labels = connected_components(graph, directed=False)
    sums = np.zeros((k, 2))
    np.add.at(sums, labels, xy)
    centres = sums / np.bincount(labels, minlength=k)[:, None]
    return (centres, labels) if return_labels else centres


def extract_trunks(cloud: np.ndarray, height_offset_m: float = 1.0, **kwargs) -> np.ndarray:
    """Trunk positions (K,2) from a map point cloud (N,3) (Li et al. Algorithm 1).

    Keyword arguments set ``forestslam._core.TrunkExtractionConfig`` fields (voxel_m,
    neighbour_radius_m, cluster_tolerance_m, min_cluster_points, max_cluster_points,
    ground_cell_m, band_min_m, band_max_m, min_cluster_height_m, max_cluster_radius_m).
    """
    from forestslam import _core

    cloud = np.asarray(cloud, dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise InputError(f"extract_trunks: cloud must have shape (N,3), got {cloud.shape}")
    cfg = _core.TrunkExtractionConfig()
    cfg.height_offset_m = height_offset_m
    for key, value in kwargs.items():
        if not hasattr(cfg, key):
            raise InputError(f"extract_trunks: unknown option {key}")
        setattr(cfg, key, value)
    xy = _core.extract_trunks(np.ascontiguousarray(cloud), cfg).xy
    return np.asarray(xy)
