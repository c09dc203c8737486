"""Stem diameter: circle fit on the breast-height band and the SAC cylinder, with quality;
real stem slice from a mobile scanner (lidR) when ../shared/data is present."""

from pathlib import Path

import numpy as np
import pytest

from forestslam.perception import estimate_diameter

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def stem_arc(r, noise, seed, centre=(8.0, 3.0)):
    rng = np.random.default_rng(seed)
    facing = np.arctan2(-centre[1], -centre[0])
    a, z = np.meshgrid(
        np.arange(facing - np.pi / 3, facing + np.pi / 3, 0.05), np.arange(0.2, 3, 0.1)
    )
    a, z = a.ravel(), z.ravel()
    rr = r + rng.normal(0, noise, a.size)
    pts = np.c_[centre[0] + rr * np.cos(a), centre[1] + rr * np.sin(a), z]
    return pts, np.c_[np.cos(a), np.sin(a), np.zeros_like(a)]


def test_partial_noisy_stem():
    errors = []
    for seed in range(10):
        pts, normals = stem_arc(0.2, 0.01, seed)
        d = estimate_diameter(pts, 0.0, normals)
        assert d.method in ("circle", "cylinder")
        assert d.circle.valid
        assert d.circle.arc_coverage == pytest.approx(1 / 3, abs=0.07)
        np.testing.assert_allclose(d.centre, [8.0, 3.0, 1.3], atol=0.03)
        errors.append(abs(d.dbh - 0.4))
    assert np.mean(errors) < 0.02 and max(errors) < 0.04


def test_impossible_radius_rejected_and_no_points():
    pts, _ = stem_arc(1.2, 0.0, 0)
    assert np.isnan(estimate_diameter(pts, 0.0).dbh)
    assert np.isnan(estimate_diameter(np.zeros((0, 3)), 0.0).dbh)


def test_real_stem_slice_stable_under_resampling():
    path = DATA / "stem" / "lidr_dbh_slice.laz"
    if not path.is_file():
        pytest.skip(f"real data not available: {path}")
    from forestslam import _core
    from forestslam.io import read_cloud

    pts = read_cloud(path).points
    config = _core.CircleFitConfig()
    config.inlier_threshold_m = 0.02
    fit = _core.fit_circle(np.ascontiguousarray(pts[:, :2]), config)
    assert fit.valid
    assert 0.1 < 2 * fit.radius < 1.0
    rng = np.random.default_rng(0)
    dbh = []
    for _ in range(10):
        sub = pts[rng.choice(len(pts), len(pts) // 2, replace=False), :2]
        dbh.append(2 * _core.fit_circle(np.ascontiguousarray(sub), config).radius)
    assert np.std(dbh) < 0.01  # half the points: DBH stable within 1 cm
    assert abs(np.median(dbh) - 2 * fit.radius) < 0.01
