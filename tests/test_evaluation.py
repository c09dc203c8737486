"""Evaluation metrics against hand-computed values."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from forestslam.errors import InputError
from forestslam.evaluation import associate, trajectory_errors, tree_errors, umeyama


def make_pose(x, y, z=0.0, yaw=0.0, roll=0.0):
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", [roll, 0.0, yaw]).as_matrix()
    t[:3, 3] = [x, y, z]
    return t


def test_associate_nearest_within_dt_one_to_one():
    a = np.array([0.0, 0.1, 0.2, 0.3])
    b = np.array([0.005, 0.11, 0.5, 0.195])
    ia, ib = associate(a, b, max_dt=0.02)
    assert ia.tolist() == [0, 1, 2]
    assert ib.tolist() == [0, 1, 3]
    # two stamps of a claim the same b: the closer one keeps it
    ia, ib = associate(np.array([0.0, 0.01]), np.array([0.008]), max_dt=0.02)
    assert ia.tolist() == [1] and ib.tolist() == [0]
    ia, ib = associate(np.zeros(0), b)
    assert len(ia) == 0 and len(ib) == 0


def test_umeyama_recovers_rigid_transform_and_stays_proper():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    truth = make_pose(1.0, -2.0, 0.5, yaw=0.7, roll=0.1)
    dst = src @ truth[:3, :3].T + truth[:3, 3]
    np.testing.assert_allclose(umeyama(src, dst), truth, atol=1e-12)
    planar = src.copy()
    planar[:, 2] = 0.0
    t = umeyama(planar, planar @ truth[:3, :3].T)
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(InputError):
        umeyama(np.zeros((0, 3)), np.zeros((0, 3)))


def test_trajectory_errors_scale_error_hand_computed():
    # truth: 21 poses along x, 1 m apart; estimate stretched by 10 %
    stamps = np.arange(21) * 0.1
    gt = np.stack([make_pose(float(i), 0.0) for i in range(21)])
    est = np.stack([make_pose(1.1 * i, 0.0) for i in range(21)])
    m = trajectory_errors(stamps, est, stamps + 0.001, gt)
    # residual after alignment: 0.1 (i - 10); RMSE = 0.1 sqrt(sum k^2, k=-10..10 / 21)
    assert m["ate_rmse_m"] == pytest.approx(0.1 * np.sqrt(770 / 21), abs=1e-9)
    assert m["rpe_percent_10m"] == pytest.approx(10.0, abs=1e-9)  # 11 m for 10 m
    assert m["rpe_segments"] == 11
    assert m["final_drift_m"] == pytest.approx(2.0, abs=1e-9)
    assert m["path_length_m"] == pytest.approx(20.0)
    assert m["n_associated"] == 21


def test_trajectory_errors_zero_for_estimate_in_another_frame():
    stamps = np.arange(40) * 0.1
    ang = np.linspace(0, 2 * np.pi, 40)
    gt = np.stack([make_pose(10 * np.cos(a), 10 * np.sin(a), 0.1 * a, yaw=a) for a in ang])
    frame = make_pose(3.0, -1.0, 0.2, yaw=-1.2)  # estimate frame = a different world frame
    est = np.einsum("ij,njk->nik", np.linalg.inv(frame), gt)
    m = trajectory_errors(stamps, est, stamps, gt)
    assert m["ate_rmse_m"] < 1e-9
    assert m["rpe_percent_10m"] < 1e-9
    assert m["final_drift_m"] < 1e-9
    np.testing.assert_allclose(m["alignment"], frame, atol=1e-9)


def test_trajectory_errors_no_overlap_is_input_error():
    gt = np.stack([np.eye(4)] * 3)
    with pytest.raises(InputError):
        trajectory_errors(np.array([0.0, 1.0, 2.0]), gt, np.array([10.0, 11.0, 12.0]), gt)


def test_tree_errors_hand_computed():
    path = np.array([[0.0, 0.0], [30.0, 0.0]])
    truth_xy = np.array([[0, 5], [10, 5], [20, 5], [0, 30], [30, 5]], dtype=float)
    truth_dbh = np.array([0.30, 0.20, 0.05, 0.40, 0.25])
    # estimates, in the truth frame:
    est_true = np.array(
        [
            [0.1, 5.0],  # T0, 0.1 m off, dbh +0.02
            [10.0, 5.2],  # T1, 0.2 m off, dbh -0.03
            [20.0, 5.0],  # thin T2: a true positive, not counted for recall
            [15.0, 5.0],  # nothing there: false positive
            [0.0, 29.0],  # outside the region of interest: ignored
            [0.3, 5.0],  # second claim on T0: false positive
            [10.6, 5.0],  # 0.6 m from T1, beyond the gate: false positive
        ]
    )
    est_dbh = np.array([0.32, 0.17, 0.06, 0.2, 0.3, 0.3, np.nan])
    alignment = make_pose(2.0, -1.0, yaw=np.pi / 2)
    inv = np.linalg.inv(alignment)
    est_xy = est_true @ inv[:2, :2].T + inv[:2, 3]
    m = tree_errors(est_xy, est_dbh, truth_xy, truth_dbh, path, alignment)
    assert m["n_truth"] == 3  # T0, T1, T4
    assert m["n_matched"] == 2
    assert m["recall"] == pytest.approx(2 / 3)
    assert m["n_est"] == 6
    assert m["precision"] == pytest.approx(3 / 6)
    assert m["mean_position_error_m"] == pytest.approx(0.15)
    assert m["dbh_mae_m"] == pytest.approx(0.025)
    assert m["dbh_rmse_m"] == pytest.approx(np.sqrt((0.02**2 + 0.03**2) / 2))
    assert m["dbh_bias_m"] == pytest.approx(-0.005)
    assert m["match_est_to_truth"].tolist() == [0, 1, 2, -1, -1, -1, -1]


def test_tree_errors_hungarian_beats_greedy():
    truth_xy = np.array([[0.0, 0.0], [0.7, 0.0]])
    truth_dbh = np.array([0.2, 0.2])
    est_xy = np.array([[0.3, 0.0], [-0.3, 0.0]])  # greedy would give truth 0 to estimate 0
    m = tree_errors(est_xy, np.array([0.2, 0.2]), truth_xy, truth_dbh, np.zeros((1, 2)))
    assert m["recall"] == 1.0 and m["precision"] == 1.0
    assert m["mean_position_error_m"] == pytest.approx(0.35)


def test_tree_errors_empty_estimate():
    m = tree_errors(
        np.zeros((0, 2)), np.zeros(0), np.array([[1.0, 1.0]]), np.array([0.3]), np.zeros((1, 2))
    )
    assert m["recall"] == 0.0 and m["n_est"] == 0 and np.isnan(m["precision"])
