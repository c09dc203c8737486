"""In-sweep motion of a spinning MLS frame estimated from the frame itself: the features of the
first and of the second half of the sweep are registered separately (LM from the whole frame's
pose), the rotation between the two half-sweep poses over the time between them is the rotation
rate during the sweep. Hand-held and vehicle scanners vibrate (roll / pitch rates change within a
tenth of a second), so the velocity of earlier frames cannot deskew a frame; this estimate can.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from forestslam.odometry.deskew import deskew_points, se3_log
from forestslam.tls.features import FrameFeatures

AZIMUTH_BINS = 360


def feature_times(
    features: np.ndarray, points: np.ndarray, times: np.ndarray, bins: int = AZIMUTH_BINS
) -> np.ndarray:
    """Times (F,) of features (F,3) of a spinning frame: the mean time of the frame's points
    (N,3) with times (N,) in the feature's azimuth bin (a spinning sensor's time follows the
    azimuth); bins without points are interpolated around the circle."""
    if len(features) == 0 or len(points) == 0:
        return np.zeros(len(features))
    scale = bins / (2 * np.pi)
    b = (np.floor((np.arctan2(points[:, 1], points[:, 0]) + np.pi) * scale).astype(int)) % bins
    n = np.bincount(b, minlength=bins)
    mean = np.bincount(b, weights=times, minlength=bins) / np.maximum(n, 1)
    filled = np.flatnonzero(n > 0)
    grid = np.arange(bins)
    mean = np.interp(grid, filled, mean[filled], period=bins)
    fb = (np.floor((np.arctan2(features[:, 1], features[:, 0]) + np.pi) * scale).astype(int)) % bins
    return mean[fb]


@dataclass
class SweepFeatures:
    """Feature times (relative to the frame's mid-sweep time) next to the features."""

    centre_times: np.ndarray
    real_times: np.ndarray


def sweep_feature_times(
    feats: FrameFeatures, points: np.ndarray, times: np.ndarray, t_mid: float
) -> SweepFeatures:
    real = feats.real_points
    return SweepFeatures(
        centre_times=feature_times(feats.centres, points, times) - t_mid,
        real_times=feature_times(real, points, times) - t_mid,
    )


def estimate_sweep_twist(
    lm: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], dict],
    feats: FrameFeatures,
    st: SweepFeatures,
    T_mid: np.ndarray,
    min_features: int = 30,
) -> np.ndarray | None:
    """Body-frame twist (6,) per second of the sensor during the sweep (its rotation rate,
    zero translation), from LM fits of each half
    of the sweep's features (lm(T_start, centres, radii, real) -> LM result dict) starting at
    the whole frame's pose T_mid (4,4); None when a half has too few features or does not
    register (not converged, degenerate)."""
    real = feats.real_points
    poses, t_half = [], []
    for first in (True, False):
        cm = st.centre_times < 0 if first else st.centre_times >= 0
        rm = st.real_times < 0 if first else st.real_times >= 0
        if rm.sum() < min_features:
            return None
        r = lm(
            T_mid,
            np.ascontiguousarray(feats.centres[cm]),
            np.ascontiguousarray(feats.radii[cm]),
            np.ascontiguousarray(real[rm]),
        )
        if not r["converged"] or r["degenerate"]:
            return None
        poses.append(np.asarray(r["T_target_source"]))
        t_half.append(np.concatenate([st.centre_times[cm], st.real_times[rm]]).mean())
    dt = t_half[1] - t_half[0]
    if dt <= 1e-3:
        return None
    # Only the rotation rate: half a sweep sees the ground on one side only, where a tilt and a
    # height shift trade off, so the half-sweep translations are biased; the translation during
    # a sweep (a few cm at walking speed) is left to the velocity of the previous frames.
    rate = se3_log(np.linalg.inv(poses[0]) @ poses[1])[3:] / dt
    return np.concatenate([np.zeros(3), rate])


def deskew_features(feats: FrameFeatures, st: SweepFeatures, twist: np.ndarray) -> FrameFeatures:
    """Features moved into the mid-sweep frame for a sensor moving with twist (6,) per second."""
    centres = deskew_points(feats.centres, st.centre_times, twist) if len(feats.centres) else None
    real = deskew_points(feats.real_points, st.real_times, twist)
    k = len(feats.keypoints)
    return FrameFeatures(
        centres=feats.centres if centres is None else centres,
        radii=feats.radii,
        stems=feats.stems,
        stem_radii=feats.stem_radii,
        keypoints=real[:k],
        ground=real[k:],
    )
