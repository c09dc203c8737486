"""Motion compensation of spinning scans with per-point time under constant velocity, and the
small SE(3) helpers the odometry needs (numpy, vectorised)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twist (6,) = (translation (3,), rotation vector (3,)) of a (4,4) pose. The translation is
    taken as is (not the SE(3) V^-1 t): exact for the small per-scan motions it is used on."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(4,4) pose of a twist from se3_log."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[3:]).as_matrix()
    T[:3, 3] = xi[:3]
    return T


def deskew_points(points: np.ndarray, times: np.ndarray, twist_per_s: np.ndarray) -> np.ndarray:
    """Points (N,3) measured at times (N,) s after the stamp, moved into the sensor frame at the
    stamp, for a sensor moving with the body-frame twist (6,) per second (translation, rotation):
    p0 = R(t w) p + t v. Rodrigues' formula, vectorised."""
    points = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1, 1)
    v, w = twist_per_s[:3], twist_per_s[3:]
    speed = float(np.linalg.norm(w))
    out = points + t * v
    if speed < 1e-12:
        return np.ascontiguousarray(out)
    k = w / speed
    theta = (t * speed).ravel()
    c, s = np.cos(theta), np.sin(theta)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    kdp = (k[0] * x + k[1] * y + k[2] * z) * (1.0 - c)
    # Rodrigues: p c + (k x p) s + k (k . p)(1 - c), column by column (no (N,3) temporaries)
    out[:, 0] += x * c + (k[1] * z - k[2] * y) * s + k[0] * kdp - x
    out[:, 1] += y * c + (k[2] * x - k[0] * z) * s + k[1] * kdp - y
    out[:, 2] += z * c + (k[0] * y - k[1] * x) * s + k[2] * kdp - z
    return np.ascontiguousarray(out)
