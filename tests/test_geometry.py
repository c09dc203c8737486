"""forestslam.geometry: poses, transforms, SE(3)/SE(2) exp and log, the rigid fit (seeded, against
known answers and scipy)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from forestslam import geometry as g


def random_pose(rng) -> np.ndarray:
    return g.pose3(Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 5, 3))


def test_planar_poses_and_yaw():
    T = g.planar_pose(1.0, 2.0, np.pi / 2, z=0.5)
    np.testing.assert_allclose(g.transform_points(T, [[1.0, 0.0, 0.0]]), [[1, 3, 0.5]], atol=1e-12)
    assert g.yaw_of(T) == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(g.rot2(np.array([0.3, -1.0])), [g.rot2(0.3), g.rot2(-1.0)])
    np.testing.assert_allclose(g.se2(1, 2, 0.4)[:2, :2], g.rot_z(0.4)[:2, :2])
    np.testing.assert_allclose(
        g.transform_points(g.se2(1, 2, np.pi), [[1.0, 1.0]]), [[0, 1]], atol=1e-12
    )


def test_rotation_zyx_matches_scipy_and_transform_xy_the_planar_part():
    rng = np.random.default_rng(3)
    ypr = rng.uniform(-np.pi, np.pi, (6, 3))
    want = Rotation.from_euler("ZYX", ypr).as_matrix()
    np.testing.assert_allclose(g.rotation_zyx(*ypr.T), want, atol=1e-12)
    np.testing.assert_allclose(g.rotation_zyx(*ypr[0]), want[0], atol=1e-12)
    xy = rng.normal(0, 3, (4, 2))
    T = g.planar_pose(1.0, -2.0, 0.7, z=5.0)
    np.testing.assert_allclose(
        g.transform_xy(T, xy), g.transform_points(T, np.c_[xy, np.zeros(4)])[:, :2], atol=1e-12
    )
    np.testing.assert_allclose(
        g.transform_xy(g.se2(1.0, -2.0, 0.7), xy), g.transform_xy(T, xy), atol=1e-12
    )


def test_inverse_single_and_batched():
    rng = np.random.default_rng(0)
    poses = np.stack([random_pose(rng) for _ in range(5)])
    np.testing.assert_allclose(g.inverse(poses) @ poses, np.tile(np.eye(4), (5, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(g.inverse(poses[0]), np.linalg.inv(poses[0]), atol=1e-12)
    np.testing.assert_allclose(g.inverse(g.se2(1, 2, 3)), np.linalg.inv(g.se2(1, 2, 3)), atol=1e-12)


def test_so3_and_se3_exp_log_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(20):
        phi = rng.normal(0, 1, 3)
        phi *= min(1.0, 3.0 / np.linalg.norm(phi))  # angle below pi: log is unique
        np.testing.assert_allclose(
            g.so3_exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-12
        )
        xi = np.concatenate([rng.normal(0, 3, 3), phi])
        np.testing.assert_allclose(g.se3_log(g.se3_exp(xi)), xi, atol=1e-9)
    # a pure translation, and a twist about z: translation along the arc
    np.testing.assert_allclose(g.se3_exp([1, 2, 3, 0, 0, 0])[:3, 3], [1, 2, 3])
    T = g.se3_exp([np.pi / 2, 0, 0, 0, 0, np.pi / 2])  # quarter circle of length pi/2
    np.testing.assert_allclose(T[:3, 3], [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(g.se3_exp(np.full(6, 1e-10)), np.eye(4), atol=1e-9)


def test_se2_exp_log_round_trip_and_agrees_with_se3():
    rng = np.random.default_rng(2)
    for _ in range(20):
        xi = np.array([*rng.normal(0, 3, 2), rng.uniform(-3.0, 3.0)])
        T = g.se2_exp(xi)
        np.testing.assert_allclose(g.se2_log(T), xi, atol=1e-9)
        T3 = g.se3_exp([xi[0], xi[1], 0, 0, 0, xi[2]])
        np.testing.assert_allclose(T3[:2, :2], T[:2, :2], atol=1e-12)
        np.testing.assert_allclose(T3[:2, 3], T[:2, 2], atol=1e-12)
    np.testing.assert_allclose(g.se2_log(g.se2_exp([0.5, -0.2, 1e-12])), [0.5, -0.2, 1e-12])


@pytest.mark.parametrize("d", [2, 3])
def test_rigid_fit_recovers_the_pose_with_noise_and_weights(d):
    rng = np.random.default_rng(3)
    T = random_pose(rng) if d == 3 else g.se2(3.0, -1.0, 2.5)
    src = rng.uniform(-10, 10, (50, d))
    dst = g.transform_points(T, src) + rng.normal(0, 0.01, (50, d))
    np.testing.assert_allclose(g.rigid_fit(src, dst), T, atol=0.01)
    bad = dst.copy()
    bad[:5] += 30.0  # outliers with zero weight do not count
    w = np.r_[np.zeros(5), np.ones(45)]
    np.testing.assert_allclose(g.rigid_fit(src, bad, w), g.rigid_fit(src[5:], dst[5:]), atol=1e-9)


def test_rigid_fit_is_never_a_reflection_and_checks_its_input():
    rng = np.random.default_rng(4)
    src = rng.normal(size=(10, 3))
    dst = src * [1, 1, -1]  # the best orthogonal map is a mirror: fit a rotation instead
    R = g.rigid_fit(src, dst)[:3, :3]
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(g.rigid_fit(src[:1], src[:1] + 2)[:3, :3], np.eye(3))
    with pytest.raises(ValueError, match="shapes"):
        g.rigid_fit(src, src[:, :2])
    with pytest.raises(ValueError, match="no point pairs"):
        g.rigid_fit(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        g.rigid_fit(np.full((2, 3), np.nan), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="weights"):
        g.rigid_fit(src, src, np.zeros(10))


def test_parse_yaw_reads_degrees_takes_units_and_warns_when_radians_are_likely(caplog):
    import logging
    import math

    from forestslam.geometry import parse_yaw

    with caplog.at_level(logging.WARNING, logger="forestslam.geometry"):
        assert parse_yaw("90", "--initial-pose") == pytest.approx(math.pi / 2)
        assert parse_yaw("0", "--initial-pose") == 0.0
        assert parse_yaw("-170.5", "--initial-pose") == pytest.approx(math.radians(-170.5))
        assert not caplog.records  # beyond 2 pi (or 0): degrees, nothing to doubt
        assert parse_yaw("1.571", "--initial-pose") == pytest.approx(math.radians(1.571))
        assert len(caplog.records) == 1 and "1.571rad" in caplog.text  # may be radians
        caplog.clear()
        assert parse_yaw(" 1.571rad", "--georef") == pytest.approx(1.571)
        assert parse_yaw("1.5deg", "--georef") == pytest.approx(math.radians(1.5))
        assert parse_yaw("45°", "--georef") == pytest.approx(math.pi / 4)
        assert not caplog.records  # a unit is explicit
    for bad in ("", "north", "nan", "1e999rad"):
        with pytest.raises(ValueError):
            parse_yaw(bad, "--georef")


def test_column_bounds_equal_numpy_exactly_and_are_zero_for_no_points():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(1000, 3)) * [100.0, 1e-3, 5e5] + [4e5, -7.0, 6e6]
    lo, hi = g.column_bounds(pts)
    assert np.array_equal(lo, pts.min(axis=0)) and np.array_equal(hi, pts.max(axis=0))
    lo, hi = g.column_bounds(np.empty((0, 3)))
    assert lo.shape == hi.shape == (3,) and not lo.any() and not hi.any()
