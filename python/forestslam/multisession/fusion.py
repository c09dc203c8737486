"""Fusing two DBH estimates of one tree (a prior map's and a run's, or two runs')."""

from __future__ import annotations

import numpy as np


def fuse_dbh(
    d_a: np.ndarray, s_a: np.ndarray, d_b: np.ndarray, s_b: np.ndarray, default_sigma_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-variance mean (K,) and its sigma (K,) of two DBH estimates with their sigmas;
    a missing or non-positive sigma counts as `default_sigma_m`, and a missing estimate
    (NaN) leaves the other one (NaN where both are missing)."""
    d_a, d_b = np.asarray(d_a, np.float64), np.asarray(d_b, np.float64)
    w_a = _weight(d_a, np.asarray(s_a, np.float64), default_sigma_m)
    w_b = _weight(d_b, np.asarray(s_b, np.float64), default_sigma_m)
    total = w_a + w_b
    with np.errstate(invalid="ignore", divide="ignore"):
        dbh = (w_a * np.nan_to_num(d_a) + w_b * np.nan_to_num(d_b)) / total
        sigma = 1.0 / np.sqrt(total)
    known = total > 0
    return np.where(known, dbh, np.nan), np.where(known, sigma, np.nan)


def _weight(d: np.ndarray, s: np.ndarray, default_sigma_m: float) -> np.ndarray:
    s = np.where(np.isfinite(s) & (s > 0), s, default_sigma_m)
    return np.where(np.isfinite(d), 1.0 / s**2, 0.0)
