"""Seeded tree layouts shared by the landmark-SLAM tests."""

from __future__ import annotations

import numpy as np


def spaced_forest(rng: np.random.Generator, lo: float, hi: float, n: int) -> np.ndarray:
    """Up to n trees (n,2) in the square [lo, hi]^2, at least 3 m apart."""
    xy = rng.uniform(lo, hi, size=(n * 4, 2))
    keep = [0]
    for i in range(1, len(xy)):
        if np.min(np.linalg.norm(xy[keep] - xy[i], axis=1)) > 3.0:
            keep.append(i)
    return xy[keep][:n]
