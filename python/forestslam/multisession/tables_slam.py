"""Tree tables (RealtimeTrees / TreeLoc layout) as SLAM input: one local tree map per pose.

Frame k of a tree table is not one scan's stems but the mapper's local map around pose k, so
consecutive frames share most trees with nearly the same errors (Wild-Places V03: one tree moves
3 cm between consecutive frames, 10-15 cm between frames 20-40 m apart, and far trees are pulled
towards the pose by about 0.1 %). Tied to landmarks as if independent, these slowly varying
errors bend the trajectory (V03, exact odometry, every frame a keyframe: 0.47 m ATE after 400 m),
while registering each frame's trees onto the previous frame's recovers the step between the
two poses to about 2 cm and 0.03 deg. So the adapter gives the SLAM, per frame:

- the odometry step corrected by that frame-to-frame tree registration, with the registration's
  covariance (the given odometry is the registration's initial guess, and the fallback with its
  own covariance when too few trees agree), and
- the frame's trees, levelled, as landmark observations: re-finding old trees and place
  recognition close the loops.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from forestslam.geometry import transform_xy
from forestslam.slam.association import associate, rigid_2d
from forestslam.slam.config import SlamConfig
from forestslam.slam.landmark_slam import lift, planar, pose2_matrix, tilt

log = logging.getLogger(__name__)


@dataclass
class TableOdometryConfig:
    # The given odometry's step error the search allows for (sigma, m): 3 sigma search radius.
    step_sigma_m: float = 0.3
    min_matches: int = 8  # trees agreeing before the registration replaces the odometry step
    min_match_fraction: float = 0.3  # ... and this fraction of the frame's trees
    # Floors of the registration's covariance (a few hundred trees would otherwise claim mm):
    # consecutive local maps share their errors, so the residual understates the step error.
    sigma_floor_m: float = 0.01
    sigma_floor_yaw_deg: float = 0.02
    fallback_sigma_m: float = 0.05  # the given odometry's step sigma when not registered
    fallback_sigma_yaw_deg: float = 0.5

    def fallback_covariance(self) -> np.ndarray:
        return np.diag(
            [self.fallback_sigma_m**2] * 2 + [math.radians(self.fallback_sigma_yaw_deg) ** 2]
        )


@dataclass
class StepResult:
    T_world_sensor: np.ndarray  # (4,4) the corrected odometry pose fed to the SLAM
    covariance: np.ndarray  # (3,3) x, y, yaw of this step
    registered: bool
    matches: int


def register_trees(
    prev_xy: np.ndarray, cur_xy: np.ndarray, T_prev_cur: np.ndarray, cfg: TableOdometryConfig
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Planar T_prev_cur (3,3) refined so that cur's trees (K,2) land on prev's (L,2), its
    (3,3) covariance and the number of matched trees; None when too few trees agree."""
    if len(prev_xy) < cfg.min_matches or len(cur_xy) < cfg.min_matches:
        return None
    slam_cfg = SlamConfig()
    pred = transform_xy(T_prev_cur, cur_xy)
    sigma = np.full(len(prev_xy), slam_cfg.landmark_sigma_floor_m)
    res = associate(
        pred,
        np.full(len(cur_xy), np.nan),
        prev_xy,
        sigma,
        np.full(len(prev_xy), np.nan),
        np.eye(2) * cfg.step_sigma_m**2,
        slam_cfg,
    )
    ok = res.matches >= 0
    n = int(ok.sum())
    if n < max(cfg.min_matches, cfg.min_match_fraction * min(len(prev_xy), len(cur_xy))):
        return None
    src, dst = pred[ok], prev_xy[res.matches[ok]]
    corr = rigid_2d(src, dst)
    resid = transform_xy(corr, src) - dst
    s2 = float(np.mean(np.sum(resid**2, axis=1))) / 2.0  # per-axis residual variance
    spread = float(np.sum((src - src.mean(axis=0)) ** 2))
    var_xy = max(s2 / n, cfg.sigma_floor_m**2)
    var_yaw = max(s2 / max(spread, 1e-9), math.radians(cfg.sigma_floor_yaw_deg) ** 2)
    return corr @ T_prev_cur, np.diag([var_xy, var_xy, var_yaw]), n


class TableOdometry:
    """Feed (odometry pose, levelled trees) per frame; returns the pose to give the SLAM."""

    def __init__(self, config: TableOdometryConfig | None = None) -> None:
        self.cfg = config or TableOdometryConfig()
        self._prev_odom: np.ndarray | None = None  # (4,4) given odometry of the previous frame
        self._prev_fed: np.ndarray | None = None  # (3,3) planar pose fed for it
        self._prev_xy = np.zeros((0, 2))
        self.registered = 0
        self.fallbacks = 0

    def step(self, T_odom: np.ndarray, trees_xy: np.ndarray) -> StepResult:
        cfg = self.cfg
        T_odom = np.asarray(T_odom, dtype=np.float64)
        trees_xy = np.asarray(trees_xy, dtype=np.float64).reshape(-1, 2)
        if self._prev_odom is None:
            fed = pose2_matrix(planar(T_odom))
            cov, registered, n = np.zeros((3, 3)), False, 0
        else:
            guess = np.linalg.inv(pose2_matrix(planar(self._prev_odom))) @ pose2_matrix(
                planar(T_odom)
            )
            reg = register_trees(self._prev_xy, trees_xy, guess, cfg)
            if reg is None:
                step = guess
                cov = cfg.fallback_covariance()
                registered, n = False, 0
                self.fallbacks += 1
            else:
                step, cov, n = reg
                registered = True
                self.registered += 1
            fed = self._prev_fed @ step
        self._prev_odom, self._prev_fed, self._prev_xy = T_odom, fed, trees_xy
        return StepResult(lift(fed) @ tilt(T_odom), cov, registered, n)


@dataclass
class TableSlamResult:
    odometry_xy: np.ndarray  # (N,2) the given (drifted) odometry
    fed_xy: np.ndarray  # (N,2) the tree-registered odometry given to the SLAM
    slam_xy: np.ndarray  # (N,2) the SLAM's trajectory
    cpu_ms_per_frame: float
    registered: int
    fallbacks: int
    stats: dict = field(default_factory=dict)
    landmark_ids: list = field(default_factory=list)  # per frame (K,) tree id per observation
    observations: list = field(default_factory=list)  # per frame (K,2) levelled trees


def table_slam_config(max_range_m: float = 20.0) -> SlamConfig:
    """SLAM settings for tree-table frames. Keyframes every quarter of the observation range
    (not by time: frames are seconds apart): each frame is a whole local map, so frames closer
    than that repeat one another's trees with the same errors (V03, 600 frames: ATE 0.43 m with
    every frame a keyframe, 0.23-0.25 m at 5-20 m). Odometry floors of a registration, not of a
    scan-to-scan odometry (which the default floors, a few cm and 1 deg per 2 m, describe).
    No online range offset: it corrects stem centres fitted to the near side of a stem in one
    scan (issue 18), while a table's trees are stems fitted in a local map seen from many sides.
    On tables its estimate has no stable value to find (first 400 frames: V04 -3.6 to +0.7 cm,
    V03 -1.4 to +2.2 cm), it only feeds residual noise back into every range (whole sessions
    without / with it: V04 0.339 / 0.570 m, V03 1.258 / 1.186 m)."""
    return SlamConfig(
        max_observation_range_m=max_range_m,
        keyframe_distance_m=max_range_m / 4.0,
        keyframe_max_interval_s=1e9,
        odom_floor_xy_m=0.005,
        odom_floor_yaw_deg=0.01,
        odom_floor_per_m=0.0,
        range_offset_gain=0.0,
    )


def level_origin(T_world_frame: np.ndarray) -> np.ndarray:
    """The odometry origin for a table: the first pose's position and heading, world z kept.
    (The first pose itself is tilted, 5-21 deg on Wild-Places: a planar SLAM in its frame would
    project the walk onto a tilted plane.)"""
    T = np.asarray(T_world_frame, dtype=np.float64)
    origin = lift(pose2_matrix(planar(T)))
    origin[2, 3] = T[2, 3]
    return origin


def run_table_slam(
    table,
    frames: np.ndarray,
    drift=None,
    slam_config: SlamConfig | None = None,
    place_recognition=None,
    odometry_config: TableOdometryConfig | None = None,
    register: bool = True,
    max_range_m: float = 20.0,
) -> TableSlamResult:
    """Run the SLAM over ``frames`` of a tree table: the odometry is the table's reference
    trajectory (relative to the first frame) corrupted by ``drift`` (a DriftInjector, or None),
    corrected by tree registration when ``register``; the trees, levelled by the reference
    gravity, are the observations. ``place_recognition``: a PlaceRecognition or None."""
    from forestslam.localization.tables import query_xy
    from forestslam.slam import LandmarkSlam

    slam = LandmarkSlam(slam_config or table_slam_config(max_range_m))
    odo = TableOdometry(odometry_config)
    T0_inv = np.linalg.inv(level_origin(table.poses[frames[0]]))
    given, fed, ids, observed = [], [], [], []
    t0 = time.process_time()
    for k in frames:
        T_odom = T0_inv @ table.poses[k]
        if drift is not None:
            T_odom = drift.apply(T_odom)
        xy, _ = query_xy(table, int(k), gravity="reference", max_range_m=max_range_m)
        if register:
            step = odo.step(T_odom, xy)
            T_fed, cov = step.T_world_sensor, step.covariance
        else:
            T_fed, cov = T_odom, odo.cfg.fallback_covariance()
        given.append(T_odom[:2, 3])
        fed.append(T_fed[:2, 3])
        stamp = float(table.stamps[k]) if table.stamps is not None else float(k)
        res = slam.add_scan(stamp, T_fed, cov, False, xy)
        ids.append(res.landmark_ids)
        observed.append(xy)
        if res.keyframe is not None and place_recognition is not None:
            place_recognition.step(slam, res.keyframe, res.T_map_sensor)
    ms = 1e3 * (time.process_time() - t0) / max(len(frames), 1)
    _, est = slam.trajectory()
    stats = dict(place_recognition.stats) if place_recognition is not None else {}
    stats["loop_closures"] = slam.loop_closures  # verified place recognition only
    stats["reassociation_corrections"] = slam.reassociation_corrections
    stats["merged_duplicates"] = slam.merged_duplicates
    stats["losses"] = slam.losses
    stats["relocalizations"] = slam.relocalizations
    stats["revisits"] = slam.revisits  # consensus moves onto older copies, declined
    stats["landmarks"] = slam.n_landmarks
    return TableSlamResult(
        np.array(given),
        np.array(fed),
        est[:, :2, 3],
        ms,
        odo.registered,
        odo.fallbacks,
        stats,
        ids,
        observed,
    )
