"""In-sweep motion of a spinning MLS frame (tls.sweep): feature times from the azimuth, and the
estimated motion applied to a frame's points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from forestslam.tls.sweep import apply_sweep, feature_times, sweep_offsets, sweep_pose


def test_feature_times_follow_the_azimuth():
    rng = np.random.default_rng(3)
    az = rng.uniform(-np.pi, np.pi, 20000)
    r = rng.uniform(2, 20, az.size)
    pts = np.column_stack([r * np.cos(az), r * np.sin(az), rng.normal(0, 1, az.size)])
    times = 0.1 * (az + np.pi) / (2 * np.pi)
    f_az = rng.uniform(-np.pi + 0.05, np.pi - 0.05, 50)
    feats = np.column_stack([5 * np.cos(f_az), 5 * np.sin(f_az), np.zeros(50)])
    expected = 0.1 * (f_az + np.pi) / (2 * np.pi)
    # One azimuth bin is 1 deg: 0.28 ms of a 0.1 s sweep.
    assert np.max(np.abs(feature_times(feats, pts, times) - expected)) < 0.0004


def test_apply_sweep_moves_points_as_the_model_says():
    rng = np.random.default_rng(4)
    pts = rng.normal(0, 5, (500, 3))
    tau = rng.uniform(-0.05, 0.05, 500)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.02, -0.01, 0.7]).as_matrix()
    T[:3, 3] = [3.0, -2.0, 0.5]
    sweep = np.array([[0.01, 0.0, 0.3, 0.4, -0.2, 0.05], [0.5, -0.3, -2.0, -3.0, 6.0, 0.0]])
    out = apply_sweep(pts, tau, T, sweep)
    # Independently, point by point: in the target frame the point moves by exp(w(tau)) about
    # the sensor position plus t(tau); back into the sensor frame at tau = 0.
    for i in range(0, 500, 25):
        c = tau[i] * sweep[0] + tau[i] ** 2 * sweep[1]
        q = T[:3, :3] @ pts[i]  # T p minus the sensor position
        q = Rotation.from_rotvec(c[3:]).apply(q) + c[:3]
        assert np.allclose(T[:3, :3].T @ q, out[i], atol=1e-9)
    assert np.allclose(sweep_offsets(np.zeros(3), sweep), 0.0)
    # No motion, no change.
    assert np.array_equal(apply_sweep(pts, tau, T, np.zeros((2, 6))), pts)
    assert np.array_equal(apply_sweep(pts, tau, T, np.zeros((0, 6))), pts)


def test_sweep_pose_places_a_point_where_apply_sweep_does():
    rng = np.random.default_rng(5)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.01, 0.03, -1.2]).as_matrix()
    T[:3, 3] = [-4.0, 7.0, 1.1]
    sweep = np.array([[0.2, 0.1, -0.3, 0.3, 0.1, -0.05], [1.0, 0.0, 2.0, 4.0, -5.0, 0.5]])
    for tau in (-0.05, -0.01, 0.0, 0.04):
        p = rng.normal(0, 8, (1, 3))
        moved = apply_sweep(p, np.array([tau]), T, sweep)[0]
        T_tau = sweep_pose(T, sweep, tau)
        assert np.allclose(T_tau[:3, :3] @ p[0] + T_tau[:3, 3], T[:3, :3] @ moved + T[:3, 3])
        assert np.allclose(T_tau[:3, :3].T @ T_tau[:3, :3], np.eye(3))
    assert np.allclose(sweep_pose(T, sweep, 0.0), T)


def test_in_sweep_lm_without_feature_times_is_a_clear_error():
    from forestslam import _core

    rng = np.random.default_rng(6)
    target = _core.StemCentreTarget(rng.uniform(-5, 5, (2000, 3)))
    centres, radii, real = rng.normal(0, 3, (4, 3)), np.full(4, 0.15), rng.normal(0, 3, (30, 3))
    config = _core.StemCentreLmConfig()
    config.sweep_order = 2
    with pytest.raises(ValueError, match="one time per virtual centre"):
        _core.register_stem_centre_lm(target, centres, radii, real, np.eye(4), config)
    with pytest.raises(ValueError, match="one time per virtual centre"):
        _core.register_stem_centre_lm(
            target,
            centres,
            radii,
            real,
            np.eye(4),
            config,
            centre_times=np.zeros(4),
            real_times=np.zeros(29),
        )
