"""Motion compensation of spinning scans with per-point time under constant velocity, and the
small SE(3) helpers the odometry needs (numpy, vectorised)."""

from __future__ import annotations

import numpy as np

from forestslam.errors import InputError


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twist (6,) = (translation (3,), rotation vector (3,)) of a (4,4) pose. The translation is
    taken as is (not the SE(3) V^-1 t): exact for the small per-scan motions it is used on.
    The C++ motion model's own function (forestslam::odometry::poseToTwist)."""
    from forestslam import _core

    return np.asarray(_core.pose_to_twist(np.asarray(T, dtype=np.float64)))


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(4,4) pose of a twist from se3_log (forestslam::odometry::twistToPose)."""
    from forestslam import _core

    return np.asarray(_core.twist_to_pose(np.asarray(xi, dtype=np.float64).reshape(6)))


def deskew_points(points: np.ndarray, times: np.ndarray, twist_per_s: np.ndarray) -> np.ndarray:
    """Points (N,3) measured at times (N,) s after the stamp, moved into the sensor frame at the
    stamp, for a sensor moving with the body-frame twist (6,) per second (translation, rotation):
    p0 = R(t w) p + t v (Rodrigues, in C++: numpy's temporaries cost ~3 ms per VLP-16 scan).
    Rows with a non-finite time are returned unchanged."""
    from forestslam import _core

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    t = np.ascontiguousarray(times, dtype=np.float64).reshape(-1)
    if len(t) != len(points):
        raise InputError(f"deskew: {len(t)} times for {len(points)} points")
    twist = np.ascontiguousarray(twist_per_s, dtype=np.float64).reshape(6)
    return np.asarray(_core.deskew_points(points, t, twist))
