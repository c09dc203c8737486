"""Odometry pipeline: deskew geometry, and tree-based odometry on a short simulated sequence with
ground truth (the `sample` scenario, first scans only)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import Scan
from forestslam.odometry.deskew import deskew_points, se3_exp, se3_log

N_SCANS = 25


def test_se3_log_exp_round_trip():
    xi = np.array([0.3, -0.1, 0.02, 0.01, -0.02, 0.15])
    np.testing.assert_allclose(se3_log(se3_exp(xi)), xi, atol=1e-12)


def test_deskew_undoes_constant_velocity_motion():
    # Sensor moving at v (body frame) turning at w; a static world point p_w is seen at time t
    # in the sensor frame at t: p_t = T(t)^-1 p_w with T(t) = exp(t * twist).
    rng = np.random.default_rng(0)
    world = rng.uniform(-20, 20, size=(500, 3))
    times = rng.uniform(0, 0.1, size=500)
    twist = np.array([1.2, 0.1, 0.0, 0.0, 0.0, 0.4])
    inv = [np.linalg.inv(se3_exp(twist * t)) for t in times]
    seen = np.stack([T[:3, :3] @ p + T[:3, 3] for T, p in zip(inv, world, strict=True)])
    fixed = deskew_points(seen, times, twist)
    # Rotation vector and translation scale together only when the translation is expressed
    # as se3_exp does (rotation then translation): exact for this parameterisation.
    np.testing.assert_allclose(fixed, world, atol=1e-9)
    np.testing.assert_allclose(deskew_points(world, np.zeros(500), twist), world)


@pytest.fixture(scope="module")
def sample_world():
    pytest.importorskip("forestslam._core")
    from forestslam.sim.scenarios import load_scenario
    from forestslam.sim.world import build_world

    return build_world(load_scenario("sample", max_scans=N_SCANS))


def run(world, **cfg):
    from forestslam.odometry import Odometry, OdometryConfig
    from forestslam.sim.simulate import scan_at

    odo = Odometry(world.profile, OdometryConfig(**cfg))
    steps = [odo.step(scan_at(world, k)) for k in range(len(world.stamps))]
    return steps


def truth(world):
    from forestslam.sim.simulate import truth_poses

    stamps, poses = truth_poses(world)
    return stamps, poses


def relative_errors(steps, gt):
    """Per-step translation (m) and yaw (deg) errors of the relative motion, and final drift."""
    est = np.stack([s.T_world_sensor for s in steps])
    gt = np.linalg.inv(gt[0]) @ gt  # both start at the identity
    dt, dyaw = [], []
    for k in range(1, len(est)):
        e = np.linalg.inv(np.linalg.inv(gt[k - 1]) @ gt[k]) @ (np.linalg.inv(est[k - 1]) @ est[k])
        dt.append(np.linalg.norm(e[:3, 3]))
        dyaw.append(abs(math.degrees(math.atan2(e[1, 0], e[0, 0]))))
    drift = np.linalg.norm(est[-1][:3, 3] - gt[-1][:3, 3])
    return np.array(dt), np.array(dyaw), drift


def test_tree_odometry_follows_truth(sample_world):
    steps = run(sample_world)
    stamps, gt = truth(sample_world)
    assert len(steps) == N_SCANS
    np.testing.assert_allclose([s.stamp for s in steps], stamps)
    step_t, step_yaw, drift = relative_errors(steps, gt)
    path = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum()
    assert path > 1.5  # the platform really moved
    assert np.median(step_t) < 0.02 and step_t.max() < 0.08
    assert np.median(step_yaw) < 0.2
    assert drift < 0.05 * path + 0.05
    trees = [s for s in steps if s.method == "trees"]
    assert len(trees) >= 0.8 * (N_SCANS - 1)  # stems carried the registration
    assert np.mean([s.degraded for s in steps]) < 0.2
    np.testing.assert_allclose(steps[0].T_world_sensor, np.eye(4))  # the world frame
    for s in steps:
        assert s.T_world_sensor.shape == (4, 4) and s.covariance.shape == (3, 3)
        assert np.all(np.isfinite(s.covariance))
        assert {"perception", "total"} <= set(s.timing)
    for s in steps[1:]:
        assert np.all(np.linalg.eigvalsh(s.covariance) > 0)


def test_stems_without_fit_dicts_keep_poses_dbh_and_centres(sample_world):
    from forestslam.odometry import Odometry
    from forestslam.sim.simulate import scan_at

    full = Odometry(sample_world.profile)
    lean = Odometry(sample_world.profile, stem_fits=False)  # what `forestslam run` uses
    for k in range(4):
        a, b = full.step(scan_at(sample_world, k)), lean.step(scan_at(sample_world, k))
        np.testing.assert_array_equal(a.T_world_sensor, b.T_world_sensor)
        assert len(a.stems) > 0 and len(a.stems.diameters) == len(a.stems)
        assert b.stems.diameters == []
        np.testing.assert_array_equal(a.stems.xy, b.stems.xy)
        np.testing.assert_array_equal(a.stems.dbh, b.stems.dbh)
        for p, q in zip(a.stems.points, b.stems.points, strict=True):
            np.testing.assert_array_equal(p, q)


def test_scans_without_stems_fall_back_to_degraded_icp():
    from forestslam.odometry import Odometry

    # Flat ground only, sensor moving at 1 m/s: no stems, x/y unobservable -> degraded but
    # finite poses that follow the velocity prior; empty scans too; never an exception.
    g = np.mgrid[-15:15:0.2, -15:15:0.2].reshape(2, -1).T
    odo = Odometry("vlp16")
    steps = []
    for k in range(6):
        pts = np.column_stack([g - [0.1 * k, 0.0], np.full(len(g), -1.0)])
        steps.append(odo.step(Scan(0.1 * k, pts)))
    steps.append(odo.step(Scan(0.7, np.zeros((0, 3)))))
    assert all(s.degraded for s in steps[1:])
    assert all(len(s.stems) == 0 for s in steps)
    assert all(np.isfinite(s.T_world_sensor).all() for s in steps)
    again = odo.step(Scan(0.7, np.zeros((0, 3))))  # stamp not advancing: a restart, no error
    assert again.motion_restarted and np.isfinite(again.T_world_sensor).all()


def _shifted(world, shift_from: int, shift_s: float) -> list[Scan]:
    """The sample scans with every stamp from scan `shift_from` on moved by shift_s seconds
    (a paused recording, or a clock that jumps back): the platform did not move meanwhile."""
    from forestslam.sim.simulate import scan_at

    scans = []
    for k in range(len(world.stamps)):
        s = scan_at(world, k)
        stamp = s.stamp + (shift_s if k >= shift_from else 0.0)
        scans.append(Scan(stamp, s.points, s.intensity, s.ring, s.time))
    return scans


@pytest.mark.parametrize("shift_s", [120.0, -50.0])
def test_stamp_gap_or_jump_back_restarts_the_motion_model(sample_world, shift_s, caplog):
    """Issue 19, 3: the constant-velocity prediction was multiplied by a 120 s gap (a jump of
    tens of metres, kept as the pose); a stamp jumping back raised on every later scan."""
    from forestslam.odometry import Odometry

    odo = Odometry(sample_world.profile)
    with caplog.at_level("WARNING", logger="forestslam.odometry"):
        steps = [odo.step(scan) for scan in _shifted(sample_world, 12, shift_s)]
    assert [s.motion_restarted for s in steps].count(True) == 1 and steps[12].motion_restarted
    warned = [r.getMessage() for r in caplog.records if "motion model restarts" in r.getMessage()]
    gap = steps[12].stamp - steps[11].stamp
    assert len(warned) == 1 and f"{gap:+.1f} s" in warned[0] and "scan 12" in warned[0]
    _, gt = truth(sample_world)
    step_t, step_yaw, _ = relative_errors(steps, gt)
    # The two steps after the restart go without velocity (no deskew of a moving sweep): a few
    # centimetres, against tens of metres when the gap multiplied the prediction.
    restart = step_t[11:13]
    assert restart.max() < 0.15, restart
    assert np.delete(step_t, [11, 12]).max() < 0.08 and np.median(step_yaw) < 0.2


def test_bad_config_is_an_input_error():
    from forestslam.odometry import Odometry, OdometryConfig

    with pytest.raises(InputError):
        Odometry("vlp16", OdometryConfig(method="magic"))
    with pytest.raises(InputError):
        Odometry("vlp16", OdometryConfig(mode="sideways"))
