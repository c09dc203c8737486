"""Tree tables as SLAM input (multisession.tables_slam): a small synthetic tree-table sequence
(one local tree map per tilted pose, as RealtimeTrees writes them) with drift injected into the
reference odometry; the back end recovers the reference."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from forestslam.geometry import rigid_fit
from forestslam.io.tree_tables import TreeTable
from forestslam.multisession.drift import DriftInjector
from forestslam.multisession.tables_slam import level_origin, run_table_slam


def synthetic_table(seed: int = 3, n_frames: int = 70, step_m: float = 2.0) -> TreeTable:
    """Trees scattered over a stand, a curved walk of tilted poses (5-20 deg), and per frame the
    trees within 25 m in the frame of that pose, each with 4 cm of noise."""
    rng = np.random.default_rng(seed)
    trees = np.column_stack([rng.uniform(-30, 170, 900), rng.uniform(-60, 90, 900)])
    heading = np.cumsum(np.full(n_frames, np.radians(1.2)))
    xy = np.cumsum(step_m * np.column_stack([np.cos(heading), np.sin(heading)]), axis=0)
    poses, frame, xyz = [], [], []
    for k in range(n_frames):
        axis = rng.normal(size=2)
        tilt = np.radians(rng.uniform(5, 20)) * np.r_[axis / np.linalg.norm(axis), 0]
        R = Rotation.from_euler("z", heading[k]) * Rotation.from_rotvec(tilt)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R.as_matrix(), [xy[k, 0], xy[k, 1], 1.5]
        poses.append(T)
        near = trees[np.linalg.norm(trees - xy[k], axis=1) <= 25.0]
        world = np.column_stack([near + rng.normal(0, 0.04, near.shape), np.zeros(len(near))])
        xyz.append((world - T[:3, 3]) @ T[:3, :3])
        frame.append(np.full(len(near), k))
    n = sum(len(f) for f in frame)
    return TreeTable(
        frame=np.concatenate(frame),
        xyz=np.concatenate(xyz),
        dbh_m=np.full(n, np.nan),
        axis=np.full((n, 3), np.nan),
        reconstructed=np.ones(n, dtype=bool),
        poses=np.stack(poses),
        stamps=3.0 * np.arange(n_frames),
    )


def ate(est: np.ndarray, ref: np.ndarray) -> float:
    T = rigid_fit(est, ref)
    return float(np.sqrt(np.mean(np.sum((est @ T[:2, :2].T + T[:2, 2] - ref) ** 2, axis=1))))


def test_level_origin_keeps_world_z_up():
    table = synthetic_table(n_frames=2)
    origin = level_origin(table.poses[0])
    assert np.allclose(origin[:3, 2], [0, 0, 1])
    assert np.allclose(origin[:3, 3], table.poses[0][:3, 3])
    rel = np.linalg.inv(origin) @ table.poses[0]
    assert abs(np.arctan2(rel[1, 0], rel[0, 0])) < 1e-9  # heading of the first pose kept


def test_drift_is_recovered_from_the_trees():
    table = synthetic_table()
    frames = table.frames
    ref = (np.linalg.inv(level_origin(table.poses[0])) @ table.poses[frames])[:, :2, 3]
    res = run_table_slam(table, frames, DriftInjector(0.02, 1.0), max_range_m=20.0)
    assert res.fallbacks == 0
    assert ate(res.odometry_xy, ref) > 1.0  # the injected drift is large
    assert ate(res.fed_xy, ref) < 0.1
    assert ate(res.slam_xy, ref) < 0.1
    # consecutive frames' trees are tied to the same landmarks, not mapped again
    assert (res.landmark_ids[-1] >= 0).mean() > 0.8


def test_without_registration_the_landmarks_alone_recover_it():
    table = synthetic_table()
    frames = table.frames
    ref = (np.linalg.inv(level_origin(table.poses[0])) @ table.poses[frames])[:, :2, 3]
    res = run_table_slam(table, frames, DriftInjector(0.02, 1.0), register=False)
    assert ate(res.slam_xy, ref) < 0.1
