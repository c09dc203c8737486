"""Stems and DBH of a plot map merged from mobile frames: stem walls as thick as the mobile
scanner's range noise (VLP-16: 1.5 cm sigma) must still be found and measured."""

from __future__ import annotations

import numpy as np
from tls_world import stand

from forestslam.tls import TlsConfig
from forestslam.tls.trees import plot_trees


def noisy_map(trees: np.ndarray, noise_m: float, seed: int = 2) -> np.ndarray:
    """Flat ground and full stem circles (seen from all sides, as a merged MLS map) with radial
    and vertical noise of noise_m."""
    rng = np.random.default_rng(seed)
    g = np.arange(-11.0, 11.0, 0.05)
    gx, gy = np.meshgrid(g, g)
    parts = [np.column_stack([gx.ravel(), gy.ravel(), rng.normal(0, 0.01, gx.size)])]
    for x, y, dbh in trees:
        n = 40000
        a = rng.uniform(-np.pi, np.pi, n)
        r = dbh / 2 + rng.normal(0, noise_m, n)
        z = rng.uniform(0.0, 4.0, n)
        parts.append(np.column_stack([x + r * np.cos(a), y + r * np.sin(a), z]))
    return np.concatenate(parts)


def test_stems_of_a_noisy_merged_map_are_found_and_measured():
    trees = stand(seed=7)
    cfg = TlsConfig()
    found = plot_trees(noisy_map(trees, 0.015), cfg.trees, cfg.features)
    assert len(found) == len(trees)
    for k in range(len(trees)):
        d = np.linalg.norm(found.xyz[:, :2] - trees[k, :2], axis=1)
        j = int(np.argmin(d))
        assert d[j] < 0.01
        assert abs(found.dbh_m[j] - trees[k, 2]) < 0.015
