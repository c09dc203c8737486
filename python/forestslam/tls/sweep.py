"""Motion of a spinning MLS frame during its own sweep (continuous time).

A hand-held or vehicle scanner vibrates: roll, pitch and height change within the 0.1 s of a
sweep, so no single rigid pose (nor a constant velocity taken from earlier frames) places the
whole sweep; on the simulated 1 deg / 0.7-6 Hz walk the ground of frames placed with their TRUE
pose and a constant-velocity deskew still errs by about 3 cm (see bench/tls_bench.py). The
stem-centre LM can estimate, besides the pose, a low-order polynomial in time of the motion
during the sweep (StemCentreLmConfig.sweep_order); each feature then needs its time, and the
frame's points are moved with the estimated motion before they join the map.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

AZIMUTH_BINS = 360


def feature_times(
    features: np.ndarray, points: np.ndarray, times: np.ndarray, bins: int = AZIMUTH_BINS
) -> np.ndarray:
    """Times (F,) of features (F,3) of a spinning frame: the mean time of the frame's points
    (N,3) with times (N,) in the feature's azimuth bin (a spinning sensor's time follows the
    azimuth); bins without points are interpolated around the circle."""
    features = np.asarray(features, dtype=np.float64).reshape(-1, 3)
    if len(features) == 0 or len(points) == 0:
        return np.zeros(len(features))
    scale = bins / (2 * np.pi)
    b = np.floor((np.arctan2(points[:, 1], points[:, 0]) + np.pi) * scale).astype(np.int64) % bins
    n = np.bincount(b, minlength=bins)
    mean = np.bincount(b, weights=times, minlength=bins) / np.maximum(n, 1)
    filled = np.flatnonzero(n > 0)
    mean = np.interp(np.arange(bins), filled, mean[filled], period=bins)
    fb = (
        np.floor((np.arctan2(features[:, 1], features[:, 0]) + np.pi) * scale).astype(np.int64)
        % bins
    )
    return mean[fb]


def sweep_offsets(tau: np.ndarray, sweep: np.ndarray) -> np.ndarray:
    """(N,6) in-sweep motion [t, w] at times tau (N,) of coefficients sweep (K,6) (row k-1 the
    coefficient of tau^k), see StemCentreLmResult::sweep."""
    tau = np.asarray(tau, dtype=np.float64)
    out = np.zeros((len(tau), 6))
    pw = np.ones_like(tau)
    for row in np.asarray(sweep, dtype=np.float64).reshape(-1, 6):
        pw = pw * tau
        out += pw[:, None] * row[None, :]
    return out


def apply_sweep(
    points: np.ndarray, tau: np.ndarray, T: np.ndarray, sweep: np.ndarray
) -> np.ndarray:
    """Points (N,3) of the frame (sensor frame at the registration time, measured at times tau
    (N,) from it) moved by the estimated in-sweep motion sweep (K,6) of the frame with pose T
    (4,4), returned in the same sensor frame: T^-1 (exp(w(tau)) (T p - o) + o + t(tau)), o the
    sensor position. Unchanged when sweep is empty or zero."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sweep = np.asarray(sweep, dtype=np.float64).reshape(-1, 6)
    if len(points) == 0 or not np.any(sweep):
        return points
    R = T[:3, :3]
    c = sweep_offsets(tau, sweep)
    q = points @ R.T  # T p - o
    q = Rotation.from_rotvec(c[:, 3:]).apply(q) + c[:, :3]
    return np.ascontiguousarray(q @ R)


def sweep_pose(T: np.ndarray, sweep: np.ndarray, tau: float) -> np.ndarray:
    """(4,4) the in-sweep motion sweep (K,6) at time tau applied to the frame's pose T (4,4):
    the rotation exp(w(tau)) about the sensor position, then the shift t(tau)."""
    sweep = np.asarray(sweep, dtype=np.float64).reshape(-1, 6)
    c = sweep_offsets(np.array([float(tau)]), sweep)[0]
    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec(c[3:]).as_matrix()
    o = T[:3, 3]
    E[:3, 3] = o - E[:3, :3] @ o + c[:3]
    return E @ T
