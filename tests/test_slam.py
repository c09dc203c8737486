"""Landmark SLAM: pose graph with known answers, association under noise."""

import math

import numpy as np
import pytest

from forestslam.evaluation import trajectory_errors, tree_errors
from forestslam.slam import LandmarkSlam, SlamConfig, associate
from forestslam.slam.height import HeightGraph


def square_path(side=20.0, step=0.1):
    """Planar poses (N,3) around a square, turning on the spot at the corners."""
    poses = []
    x, y, yaw = 0.0, 0.0, 0.0
    for _ in range(4):
        for _ in range(int(round(side / step))):
            poses.append((x, y, yaw))
            x += step * math.cos(yaw)
            y += step * math.sin(yaw)
        for k in range(10):
            poses.append((x, y, yaw + k * math.pi / 20))
        yaw += math.pi / 2
    poses.append((x, y, yaw))
    return np.array(poses)


def matrix(p):
    t = np.eye(4)
    c, s = math.cos(p[2]), math.sin(p[2])
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = p[:2]
    return t


def forest(rng, n=60):
    xy = rng.uniform(-10, 30, size=(n * 3, 2))
    keep = [0]
    for i in range(1, len(xy)):  # minimum spacing 3 m
        if np.min(np.linalg.norm(xy[keep] - xy[i], axis=1)) > 3.0:
            keep.append(i)
    return xy[keep][:n]


def run(
    truth,
    trees,
    rng,
    odom_yaw_bias=0.0,
    obs_noise=0.0,
    clutter=0,
    cfg=None,
    view_m=12.0,
    heights=None,
    z_drift_per_m=0.0,
    range_bias=0.0,
):
    """Feed the simulated scans; odometry drifts by a yaw bias per step (and in z by
    z_drift_per_m per metre; tree centre heights `heights` (M,) then observed with it)."""
    slam = LandmarkSlam(cfg or SlamConfig())
    odom = truth[0].copy()
    z_err = 0.0
    for i, p in enumerate(truth):
        if i:
            prev = truth[i - 1]
            c, s = math.cos(prev[2]), math.sin(prev[2])
            d = p[:2] - prev[:2]
            step = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], p[2] - prev[2]])
            step[2] += odom_yaw_bias * np.linalg.norm(d) * 10
            c, s = math.cos(odom[2]), math.sin(odom[2])
            odom = odom + np.array([c * step[0] - s * step[1], s * step[0] + c * step[1], step[2]])
            z_err += z_drift_per_m * np.linalg.norm(d)
        c, s = math.cos(p[2]), math.sin(p[2])
        rel = trees - p[:2]
        local = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
        vis = np.linalg.norm(local, axis=1) < view_m
        obs = local[vis] + rng.normal(scale=obs_noise, size=(int(vis.sum()), 2))
        if range_bias:  # centres fitted to the visible side: nearer (or farther) than the axis
            r = np.linalg.norm(obs, axis=1, keepdims=True)
            obs = obs * (r + range_bias) / r
        if clutter:
            obs = np.vstack([obs, rng.uniform(-12, 12, size=(clutter, 2))])
        z = None
        if heights is not None:  # heights seen from a sensor whose odometry z is off by z_err
            z = heights[vis] + z_err + rng.normal(scale=obs_noise, size=int(vis.sum()))
            z = np.concatenate([z, np.full(len(obs) - len(z), 1.3)])
        cov = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
        t_odom = matrix(odom)
        t_odom[2, 3] = z_err
        slam.add_scan(i * 0.1, t_odom, cov, False, obs, None, z)
    return slam


def ate(slam, truth):
    stamps, poses = slam.trajectory()
    gt = np.stack([matrix(p) for p in truth])
    return trajectory_errors(stamps, poses, stamps, gt)


def test_square_loop_exact_data_gives_exact_answer():
    rng = np.random.default_rng(0)
    truth = square_path()
    trees = forest(rng)
    slam = run(truth, trees, rng)
    m = ate(slam, truth)
    assert m["ate_rmse_m"] < 1e-3
    lm, nobs = slam.landmarks()
    t = tree_errors(
        lm, np.full(len(lm), np.nan), trees, np.full(len(trees), 0.3), truth[:, :2], max_dist_m=11.0
    )
    assert t["recall"] == 1.0 and t["precision"] == 1.0
    assert t["mean_position_error_m"] < 1e-3
    assert (nobs >= 3).all()


def test_square_loop_with_drift_and_noise_closes_the_loop():
    rng = np.random.default_rng(1)
    truth = square_path(side=30.0)
    trees = forest(rng, 80)
    # 0.012 deg of yaw error per 0.1 m: several metres of odometry drift over the loop
    slam = run(
        truth,
        trees,
        rng,
        odom_yaw_bias=math.radians(0.012),
        obs_noise=0.05,
        clutter=1,
        view_m=8.0,
    )
    stamps, odom = slam.odometry()
    gt = np.stack([matrix(p) for p in truth])
    m_odom = trajectory_errors(stamps, odom, stamps, gt)
    m = ate(slam, truth)
    assert m_odom["final_drift_m"] > 2.0
    assert m["ate_rmse_m"] < 0.1
    assert m["final_drift_m"] < 0.15
    lm, _ = slam.landmarks()
    t = tree_errors(
        lm, np.full(len(lm), np.nan), trees, np.full(len(trees), 0.3), truth[:, :2], max_dist_m=7.0
    )
    assert t["recall"] >= 0.95
    assert t["precision"] >= 0.95  # random clutter never seen twice at one place
    assert t["mean_position_error_m"] < 0.1


def test_association_recovers_shifted_observations_under_noise():
    rng = np.random.default_rng(2)
    lm = forest(rng, 40)
    cfg = SlamConfig()
    sel = rng.choice(len(lm), 15, replace=False)
    # drift: the predicted pose is 1.2 m and 2 deg off; observations carry 5 cm noise
    ang = math.radians(2.0)
    rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
    obs = (lm[sel] - lm[sel].mean(0)) @ rot.T + lm[sel].mean(0) + [1.2, -0.4]
    obs += rng.normal(scale=0.05, size=obs.shape)
    obs = np.vstack([obs, [[100.0, 100.0]]])  # a stem far from every tree
    res = associate(
        obs,
        np.full(len(obs), np.nan),
        lm,
        np.full(len(lm), 0.03),
        np.full(len(lm), np.nan),
        np.eye(2) * 0.6**2,
        cfg,
    )
    assert res.matches[:-1].tolist() == sel.tolist()
    assert res.matches[-1] == -1
    assert res.support >= 14
    # without the consensus step the same shift gives no (or wrong) matches
    plain = associate(
        obs,
        np.full(len(obs), np.nan),
        lm,
        np.full(len(lm), 0.03),
        np.full(len(lm), np.nan),
        np.eye(2) * 0.01**2,
        cfg,
        use_consensus=False,
    )
    assert (plain.matches[:-1] == sel).sum() < 3


def test_association_rejects_incompatible_dbh_and_handles_empty():
    cfg = SlamConfig()
    lm = np.array([[0.0, 0.0], [5.0, 0.0]])
    res = associate(
        np.array([[0.1, 0.0]]),
        np.array([0.60]),
        lm,
        np.full(2, 0.03),
        np.array([0.2, 0.6]),
        np.eye(2) * 0.01,
        cfg,
    )
    assert res.matches.tolist() == [-1]
    empty = associate(
        np.zeros((0, 2)), np.zeros(0), lm, np.full(2, 0.03), np.full(2, np.nan), np.eye(2), cfg
    )
    assert len(empty.matches) == 0


def test_scans_without_trees_are_bridged_by_odometry():
    slam = LandmarkSlam()
    for i in range(30):
        p = np.array([0.1 * i, 0.0, 0.0])
        slam.add_scan(0.1 * i, matrix(p), None, i % 7 == 0, np.zeros((0, 2)))
    stamps, poses = slam.trajectory()
    assert len(stamps) == 30
    np.testing.assert_allclose(poses[:, 0, 3], 0.1 * np.arange(30), atol=1e-6)
    assert slam.n_landmarks == 0


@pytest.mark.parametrize("kernel", ["cauchy", "none"])
def test_robust_kernel_options(kernel):
    rng = np.random.default_rng(3)
    truth = square_path(side=8.0)
    trees = forest(rng, 20)
    slam = run(truth, trees, rng, cfg=SlamConfig(robust_kernel=kernel))
    assert ate(slam, truth)["ate_rmse_m"] < 1e-3


def test_root_config_yaml_sections(tmp_path):
    from forestslam.config import config_to_dict, load_config
    from forestslam.errors import InputError

    path = tmp_path / "c.yaml"
    path.write_text("slam:\n  keyframe_distance_m: 1.5\nmapping:\n  dbh_band_m: [1.2, 1.4]\n")
    cfg = load_config(path)
    assert cfg.slam.keyframe_distance_m == 1.5
    assert cfg.mapping.dbh_band_m == (1.2, 1.4)
    assert config_to_dict(load_config(None))["slam"]["robust_kernel"] == "huber"
    path.write_text("slam:\n  keyframe_distance: 1.5\n")
    with pytest.raises(InputError, match="keyframe_distance"):
        load_config(path)
    path.write_text("nonsense:\n  a: 1\n")
    with pytest.raises(InputError, match="nonsense"):
        load_config(path)


def test_height_graph_known_answer():
    # two trees at heights 1.0 and 2.0; the odometry z is off by 0, 0.1, 0.2 at three keyframes
    g = HeightGraph(obs_sigma_m=0.001, step_sigma_m=10.0)  # observations dominate
    for kf, off in enumerate([0.0, 0.1, 0.2]):
        g.add_keyframe(1.0)
        g.add_observation(kf, 0, 1.0 - off)
        g.add_observation(kf, 1, 2.0 - off)
    dz, h = g.solve(3)
    np.testing.assert_allclose(dz, [0.0, 0.1, 0.2], atol=1e-5)
    np.testing.assert_allclose(h[:2], [1.0, 2.0], atol=1e-5)
    assert np.isnan(h[2])  # a tree never seen has no height
    g.truncate(1)
    dz, h = g.solve(2)
    assert len(dz) == 1 and abs(h[1] - 2.0) < 1e-5
    assert HeightGraph().solve(4)[1].shape == (4,)  # empty: NaN heights, no crash


def test_tree_heights_without_height_correction_are_the_observed_means():
    """The default (no height correction) still gives every tree a height: the mean of its
    observed centre heights (the prior-map placement levels a run's map on them)."""
    rng = np.random.default_rng(4)
    truth = square_path(side=20.0)
    trees = forest(rng, 60)
    heights = 1.3 + 0.3 * np.sin(trees[:, 0] / 7.0)
    slam = run(truth, trees, rng, obs_noise=0.03, heights=heights, cfg=SlamConfig())
    lm, _ = slam.landmarks()
    h = slam.landmark_heights()
    nearest = np.argmin(np.linalg.norm(lm[:, None] - trees[None], axis=2), axis=1)
    assert np.isfinite(h).all()
    assert np.median(np.abs(h - heights[nearest])) < 0.02  # no z drift here


def test_height_correction_removes_odometry_z_drift():
    rng = np.random.default_rng(3)
    truth = square_path(side=20.0)
    trees = forest(rng, 60)
    heights = 1.3 + 0.3 * np.sin(trees[:, 0] / 7.0) + 0.2 * np.cos(trees[:, 1] / 5.0)
    # 1 cm of z drift per metre: 0.8 m over the loop
    cfg = SlamConfig(height_correction=True)
    slam = run(truth, trees, rng, obs_noise=0.03, heights=heights, z_drift_per_m=0.01, cfg=cfg)
    stamps, poses = slam.trajectory()
    _, odom = slam.odometry()
    assert abs(odom[-1, 2, 3]) > 0.7
    z = poses[:, 2, 3]
    assert np.sqrt(np.mean(z**2)) < 0.05  # truth z is 0 throughout
    assert abs(z[-1]) < 0.05
    lm, _ = slam.landmarks()
    h = slam.landmark_heights()
    nearest = np.argmin(np.linalg.norm(lm[:, None] - trees[None], axis=2), axis=1)
    assert np.isfinite(h).all()
    assert np.median(np.abs(h - heights[nearest])) < 0.05
    off = run(
        truth,
        trees,
        rng,
        obs_noise=0.03,
        heights=heights,
        z_drift_per_m=0.01,
        cfg=SlamConfig(height_correction=False),
    )
    assert abs(off.trajectory()[1][-1, 2, 3]) > 0.7  # without it the drift stays


def test_failed_update_is_rolled_back_and_the_next_keyframe_works():
    """A keyframe whose odometry is absurd (1e20 m, what a per-point time of 1e20 s made of a
    scan) fails the iSAM2 update. It left its variable half added: every later keyframe failed
    with 'key "x11" already exists' (380 of 441 scans here). Now the update is undone."""
    from forestslam.errors import ProcessingError

    rng = np.random.default_rng(0)
    truth = square_path(side=10.0)
    trees = forest(rng)
    slam = LandmarkSlam(SlamConfig())
    failed = []
    for i, p in enumerate(truth):
        c, s = math.cos(p[2]), math.sin(p[2])
        rel = trees - p[:2]
        local = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
        T = matrix(p)
        if i == 60:
            T[:2, 3] = 1e20
        try:
            slam.add_scan(
                i * 0.1,
                T,
                np.diag([1e-4, 1e-4, 1e-5]),
                False,
                local[np.linalg.norm(local, axis=1) < 12.0],
            )
        except ProcessingError:
            failed.append(i)
    assert failed == [60] and slam.failed_updates == 1
    stamps, poses = slam.trajectory()
    assert len(stamps) == len(truth) - 1 and 6.0 not in stamps.round(6)
    keep = np.delete(np.arange(len(truth)), 60)
    gt = np.stack([matrix(truth[i]) for i in keep])
    assert np.abs(poses[:, :3, 3] - gt[:, :3, 3]).max() < 1e-6
    lm, _ = slam.landmarks()
    t = tree_errors(
        lm, np.full(len(lm), np.nan), trees, np.full(len(trees), 0.3), truth[:, :2], max_dist_m=11
    )
    assert t["recall"] == 1.0 and t["precision"] == 1.0 and t["mean_position_error_m"] < 1e-6


def test_common_range_bias_of_stem_centres_is_estimated_and_removed():
    """Stem centres 4 cm nearer than the axes (a fit to the visible side): views from opposite
    sides disagree by 8 cm and bend the trajectory. The online range offset removes part of the
    bias (trees seen from one side only absorb the rest, so it under-corrects, never over)."""
    truth = square_path(side=20.0)
    trees = forest(np.random.default_rng(5), 60)
    kw = dict(obs_noise=0.01, range_bias=-0.04)
    on = run(truth, trees, np.random.default_rng(6), **kw)
    off = run(truth, trees, np.random.default_rng(6), cfg=SlamConfig(range_offset_gain=0.0), **kw)
    assert 0.01 < on.range_offset <= 0.04
    assert off.range_offset == 0.0
    assert ate(on, truth)["ate_rmse_m"] < 0.7 * ate(off, truth)["ate_rmse_m"]
    unbiased = run(truth, trees, np.random.default_rng(6), obs_noise=0.01)
    assert abs(unbiased.range_offset) < 0.01  # no bias, no offset
