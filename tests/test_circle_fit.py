"""Robust circle fit binding (forestslam._core.fit_circle): known circles, partial arcs,
outliers, degenerate input, the typed options and the read-only result with its covariance."""

import numpy as np
import pytest

from forestslam import _core


def options(**values):
    """A CircleFitConfig (C++ defaults) with `values` set, through the config bridge."""
    from forestslam.core_bridge import core_struct

    return core_struct("CircleFitConfig", values, "test")


def arc(cx, cy, r, a0, a1, n, noise, seed):
    rng = np.random.default_rng(seed)
    a = np.linspace(a0, a1, n)
    rr = r + rng.normal(0, noise, n)
    return np.c_[cx + rr * np.cos(a), cy + rr * np.sin(a)]


def test_exact_circle():
    f = _core.fit_circle(arc(2.0, -1.0, 0.3, 0, 6.2, 50, 0.0, 0))
    assert f.valid
    np.testing.assert_allclose(f.centre, [2.0, -1.0], atol=1e-6)
    assert f.radius == pytest.approx(0.3, abs=1e-6)
    assert f.inliers == 50
    assert f.arc_coverage > 0.95


def test_third_of_a_stem_with_lidar_noise():
    errors = []
    for seed in range(20):
        xy = arc(10.0, 4.0, 0.2, 2.0, 2.0 + 2 * np.pi / 3, 40, 0.005, seed)
        f = _core.fit_circle(xy, options(inlier_threshold_m=0.015))
        assert f.valid
        assert f.arc_coverage == pytest.approx(1 / 3, abs=0.06)
        errors.append(abs(f.radius - 0.2))
    assert np.mean(errors) < 0.01 and max(errors) < 0.025


def test_outliers_do_not_move_the_circle():
    rng = np.random.default_rng(1)
    xy = np.vstack([arc(0.0, 0.0, 0.25, -1, 2, 60, 0.003, 1), rng.uniform(-0.6, 0.6, (30, 2))])
    f = _core.fit_circle(xy, options(inlier_threshold_m=0.01))
    np.testing.assert_allclose(f.centre, [0, 0], atol=0.01)
    assert f.radius == pytest.approx(0.25, abs=0.01)
    a = _core.fit_circle_algebraic(xy)
    assert abs(a.radius - 0.25) + np.hypot(*a.centre) > 0.03  # robustness matters


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
    assert not f.valid
    assert np.isnan(f.radius)


def test_radius_bounds():
    xy = arc(0, 0, 2.0, 0, 1, 30, 0.0, 0)
    assert not _core.fit_circle(xy, options(max_radius_m=1.0)).valid
    assert _core.fit_circle(xy, options(max_radius_m=3.0)).valid


def test_options_are_typed_and_unknown_or_wrong_keys_are_named():
    from forestslam.errors import InputError

    assert isinstance(options(), _core.CircleFitConfig)
    assert options(seed=7).seed == 7
    with pytest.raises(InputError, match=r"test\.inlier_threshold"):
        options(inlier_threshold=0.02)
    with pytest.raises(InputError, match=r"test\.arc_sectors"):
        options(arc_sectors=36.0)


def test_result_is_read_only_and_carries_its_covariance():
    xy = arc(1.0, 2.0, 0.2, 0.0, 3.0, 60, 0.004, 3)
    f = _core.fit_circle(xy)
    with pytest.raises(AttributeError):
        f.radius = 1.0
    cov = np.asarray(f.covariance)
    assert cov.shape == (3, 3) and np.allclose(cov, cov.T)
    assert f.radius_std == pytest.approx(np.sqrt(cov[2, 2]))
    # sigma^2 (J^T J)^-1 of the inliers with n - 3 degrees of freedom, written out
    inl = xy[np.asarray(f.inlier_indices)]
    v = inl - np.asarray(f.centre)
    d = np.linalg.norm(v, axis=1)
    J = np.column_stack([-v / d[:, None], -np.ones(len(d))])
    expected = np.sum((d - f.radius) ** 2) / (len(d) - 3) * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(cov, expected, rtol=1e-9)
    assert np.isinf(_core.fit_circle(xy[:2]).radius_std)


def test_radius_std_grows_as_the_arc_shrinks_and_matches_the_scatter_of_fits():
    rng = np.random.default_rng(4)
    sigmas, spreads = [], []
    for half_angle in (np.pi, np.pi / 4):
        radii, predicted = [], []
        for _ in range(60):
            a = rng.uniform(-half_angle, half_angle, 80)
            r = 0.15 + rng.normal(0, 0.005, 80)
            fit = _core.fit_circle(
                np.c_[r * np.cos(a), r * np.sin(a)], options(inlier_threshold_m=0.02)
            )
            radii.append(fit.radius)
            predicted.append(fit.radius_std)
        sigmas.append(np.median(predicted))
        spreads.append(np.std(radii))
    assert sigmas[1] > 5 * sigmas[0]  # a quarter circle vs the full one
    for s, spread in zip(sigmas, spreads, strict=True):
        assert 0.6 * spread < s < 1.6 * spread  # the predicted spread is the fits' spread


def test_weights_fit_as_the_points_repeated_and_must_match_the_points():
    xy = arc(1.0, 2.0, 0.2, -1.0, 1.5, 60, 0.01, 7)
    counts = np.random.default_rng(2).integers(1, 5, len(xy))
    weighted = _core.fit_circle(xy, weights=counts.astype(float))
    repeated = _core.fit_circle(np.repeat(xy, counts, axis=0))
    assert weighted.radius == pytest.approx(repeated.radius, abs=1e-9)
    np.testing.assert_allclose(weighted.centre, repeated.centre, atol=1e-9)
    origins = np.tile([-3.0, 2.0], (len(xy), 1))
    rays = _core.fit_circle_rays(xy, origins, weights=counts.astype(float))
    rays_rep = _core.fit_circle_rays(np.repeat(xy, counts, axis=0), np.repeat(origins, counts, 0))
    assert rays.radius == pytest.approx(rays_rep.radius, abs=1e-9)
    with pytest.raises(ValueError, match="weights"):
        _core.fit_circle(xy, weights=np.ones(3))
    with pytest.raises(ValueError, match="weight"):
        _core.fit_circle(xy, weights=-np.ones(len(xy)))
