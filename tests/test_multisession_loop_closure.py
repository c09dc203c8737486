"""Loop closure by place recognition under injected drift: a loop whose return side crosses a
treeless clearing keeps the clearing's heading error (2 % scale, 1 deg per 10 m), so the SLAM
comes back to its first trees metres off, beyond re-association; place recognition verifies the
place and ties the trees, and only verified closures are counted."""

from __future__ import annotations

import math

import numpy as np

from forestslam.evaluation import trajectory_errors
from forestslam.geometry import planar_pose
from forestslam.multisession.drift import DriftInjector
from forestslam.multisession.loops import PlaceRecognition, PlaceRecognitionConfig
from forestslam.slam import LandmarkSlam, SlamConfig


def _stand(seed: int) -> np.ndarray:
    """Trees at least 3 m apart over the loop's area, none in a 60 m clearing on the return
    side (30 < x < 90, y > 15)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-15.0, 115.0, size=(3600, 2))
    keep = [0]
    for i in range(1, len(xy)):
        if np.min(np.linalg.norm(xy[keep] - xy[i], axis=1)) > 3.0:
            keep.append(i)
    xy = xy[keep][:900]
    clearing = (xy[:, 0] > 30.0) & (xy[:, 0] < 90.0) & (xy[:, 1] > 15.0)
    return xy[~clearing]


def _loop(step: float = 0.2) -> list[np.ndarray]:
    """A 100 m x 30 m rectangle walked once, then 40 m along its first side again."""
    corners = [(0, 0), (100, 0), (100, 30), (0, 30), (0, 0), (40, 0)]
    poses = []
    for (x0, y0), (x1, y1) in zip(corners[:-1], corners[1:], strict=True):
        n = int(math.hypot(x1 - x0, y1 - y0) / step)
        yaw = math.atan2(y1 - y0, x1 - x0)
        poses += [
            planar_pose(x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n, yaw) for i in range(n)
        ]
    return poses


def _walk(stand: np.ndarray, place_recognition: bool, seed: int = 0, loops=None):
    """The loop with drifted odometry, stems within 12 m observed with 2 cm noise; `loops`:
    the PlaceRecognition to use (default: the default one when place_recognition)."""
    rng = np.random.default_rng(seed)
    slam = LandmarkSlam(SlamConfig())
    if loops is None and place_recognition:
        loops = PlaceRecognition(PlaceRecognitionConfig())
    drift = DriftInjector(0.02, 1.0)
    truth = _loop()
    cov = np.diag([0.01**2, 0.01**2, math.radians(0.1) ** 2])
    for i, T in enumerate(truth):
        local = (stand - T[:2, 3]) @ T[:2, :2]
        seen = local[np.linalg.norm(local, axis=1) < 12.0]
        seen = seen + rng.normal(0.0, 0.02, seen.shape)
        res = slam.add_scan(i * 0.1, drift.apply(T), cov, False, seen)
        if loops is not None and res.keyframe is not None:
            loops.step(slam, res.keyframe, res.T_map_sensor)
    stamps, poses = slam.trajectory()
    ate = trajectory_errors(stamps, poses, stamps, np.stack(truth))["ate_rmse_m"]
    end_error = float(np.linalg.norm(poses[-1][:2, 3] - truth[-1][:2, 3]))
    return slam, loops, ate, end_error


def _assert_ties_are_true_trees(slam, stand: np.ndarray, min_ties: int = 6) -> None:
    """No false tie: both copies of every tied tree are the same true tree (the map frame is
    the truth's: the odometry starts at the true pose)."""
    xy, _ = slam.landmarks()
    alias = slam.aliases()
    tied = np.flatnonzero(alias >= 0)
    assert len(tied) >= min_ties

    def nearest(ids):
        return np.argmin(np.linalg.norm(xy[ids][:, None] - stand[None], axis=2), axis=1)

    np.testing.assert_array_equal(nearest(tied), nearest(alias[tied]))


def test_place_recognition_closes_a_loop_that_re_association_does_not():
    stand = _stand(3)
    slam, _, ate_without, end_without = _walk(stand, place_recognition=False)
    assert slam.loop_closures == 0  # re-association corrections are not loop closures
    assert end_without > 1.0 and ate_without > 0.8  # back on the first trees, still metres off

    slam, loops, ate, end = _walk(stand, place_recognition=True)
    assert loops.stats["closures"] >= 1
    assert slam.loop_closures == loops.stats["closures"]  # only verified closures counted
    assert ate < 0.25 and end < 0.2
    _assert_ties_are_true_trees(slam, stand)
