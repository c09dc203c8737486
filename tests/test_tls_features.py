"""Ground samples of MLS frames (real features that fix height, roll and pitch)."""

from __future__ import annotations

import numpy as np

from forestslam.tls.config import FeatureConfig
from forestslam.tls.features import ground_samples


def _frame(seed: int = 0, noise: float = 0.015) -> tuple[np.ndarray, float]:
    """Flat ground 1.2 m below the sensor (many returns per cell, range noise) plus stems."""
    rng = np.random.default_rng(seed)
    ground_z = -1.2
    xy = rng.uniform(-15, 15, (40000, 2))
    ground = np.column_stack([xy, np.full(len(xy), ground_z)])
    parts = [ground]
    for cx, cy in rng.uniform(-12, 12, (12, 2)):
        a = rng.uniform(0, 2 * np.pi, 800)
        z = rng.uniform(ground_z + 0.05, 3.0, 800)
        parts.append(np.column_stack([cx + 0.15 * np.cos(a), cy + 0.15 * np.sin(a), z]))
    pts = np.concatenate(parts)
    pts = pts + rng.normal(0, noise, pts.shape)
    return pts, ground_z


def test_ground_samples_lie_on_the_ground_without_bias():
    pts, ground_z = _frame()
    cfg = FeatureConfig()
    g = ground_samples(pts, cfg)
    assert 50 <= len(g) <= cfg.ground_max_points
    assert np.all(np.abs(g[:, 2] - ground_z) < 0.08)
    # The lowest point per cell would sit about 2.5 noise sigmas low; the samples do not.
    assert abs(np.mean(g[:, 2]) - ground_z) < 0.006
    r = np.hypot(g[:, 0], g[:, 1])
    assert np.all((r >= 1.0) & (r <= cfg.ground_max_range_m + 1e-9))
    # Spread over the frame, not bunched: samples in every quadrant.
    quadrants = {(bool(x > 0), bool(y > 0)) for x, y in g[:, :2]}
    assert len(quadrants) == 4


def test_ground_samples_degenerate_inputs():
    cfg = FeatureConfig()
    assert ground_samples(np.zeros((0, 3)), cfg).shape == (0, 3)
    assert ground_samples(np.array([[5.0, 0.0, -1.0]]), cfg).shape == (0, 3)
    cfg.ground_max_points = 0
    assert ground_samples(_frame()[0], cfg).shape == (0, 3)
