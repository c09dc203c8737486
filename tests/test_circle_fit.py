"""Robust circle fit binding (forestslam._core.fit_circle): known circles, partial arcs,
outliers, degenerate input."""

import numpy as np
import pytest

from forestslam import _core


def arc(cx, cy, r, a0, a1, n, noise, seed):
    rng = np.random.default_rng(seed)
    a = np.linspace(a0, a1, n)
    rr = r + rng.normal(0, noise, n)
    return np.c_[cx + rr * np.cos(a), cy + rr * np.sin(a)]


def test_exact_circle():
    f = _core.fit_circle(arc(2.0, -1.0, 0.3, 0, 6.2, 50, 0.0, 0))
    assert f["valid"]
    np.testing.assert_allclose(f["centre"], [2.0, -1.0], atol=1e-6)
    assert f["radius"] == pytest.approx(0.3, abs=1e-6)
    assert f["inliers"] == 50
    assert f["arc_coverage"] > 0.95


def test_third_of_a_stem_with_lidar_noise():
    errors = []
    for seed in range(20):
        xy = arc(10.0, 4.0, 0.2, 2.0, 2.0 + 2 * np.pi / 3, 40, 0.005, seed)
        f = _core.fit_circle(xy, inlier_threshold_m=0.015)
        assert f["valid"]
        assert f["arc_coverage"] == pytest.approx(1 / 3, abs=0.06)
        errors.append(abs(f["radius"] - 0.2))
    assert np.mean(errors) < 0.01 and max(errors) < 0.025


def test_outliers_do_not_move_the_circle():
    rng = np.random.default_rng(1)
    xy = np.vstack([arc(0.0, 0.0, 0.25, -1, 2, 60, 0.003, 1), rng.uniform(-0.6, 0.6, (30, 2))])
    f = _core.fit_circle(xy, inlier_threshold_m=0.01)
    np.testing.assert_allclose(f["centre"], [0, 0], atol=0.01)
    assert f["radius"] == pytest.approx(0.25, abs=0.01)
    a = _core.fit_circle_algebraic(xy)
    assert abs(a["radius"] - 0.25) + np.hypot(*a["centre"]) > 0.03  # robustness matters


@pytest.mark.parametrize(
    "xy",
    [
        np.zeros((0, 2)),
        np.array([[0.0, 0.0], [1.0, 1.0]]),
        np.c_[np.linspace(0, 1, 10), 2 * np.linspace(0, 1, 10)],  # collinear
        np.full((5, 2), np.nan),
    ],
)
def test_degenerate_input_is_invalid(xy):
    f = _core.fit_circle(np.ascontiguousarray(xy, dtype=np.float64))
    assert not f["valid"]
    assert np.isnan(f["radius"])


def test_radius_bounds():
    xy = arc(0, 0, 2.0, 0, 1, 30, 0.0, 0)
    assert not _core.fit_circle(xy, max_radius_m=1.0)["valid"]
    assert _core.fit_circle(xy, max_radius_m=3.0)["valid"]
