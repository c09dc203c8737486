"""Two sessions' tree maps become one in A's frame; maps that do not overlap are refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import read_trees_csv, read_tum, write_trees_csv, write_tum
from forestslam.multisession import align_tree_maps
from forestslam.multisession.runs import merge_runs


def _stand(seed=0, n=400, size=120.0):
    """A Poisson stand with a 2.5 m minimum spacing."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, size, (n * 3, 2))
    keep = [0]
    for i in range(1, len(xy)):
        if np.min(np.linalg.norm(xy[keep] - xy[i], axis=1)) > 2.5:
            keep.append(i)
        if len(keep) == n:
            break
    return xy[keep], rng.uniform(0.12, 0.45, len(keep))


def _session(xy, dbh, x_range, T_b_world, seed):
    """Trees seen by a session driving along y = 60 over `x_range`, in the session's frame,
    with 3 cm position and 1 cm DBH noise; its straight path; T_b_world (3,3) planar."""
    rng = np.random.default_rng(seed)
    seen = (xy[:, 0] > x_range[0]) & (xy[:, 0] < x_range[1]) & (np.abs(xy[:, 1] - 60) < 25)
    R, t = T_b_world[:2, :2], T_b_world[:2, 2]
    local = xy[seen] @ R.T + t + rng.normal(0, 0.03, (seen.sum(), 2))
    path_world = np.column_stack([np.linspace(*x_range, 60), np.full(60, 60.0)])
    return (
        local,
        dbh[seen] + rng.normal(0, 0.01, seen.sum()),
        path_world @ R.T + t,
        np.flatnonzero(seen),
    )


def _planar(x, y, yaw_deg):
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, x], [s, c, y], [0, 0, 1.0]])


def test_b_is_placed_in_a_by_localization_and_refinement():
    xy, dbh = _stand()
    a_xy, _, _, a_ids = _session(xy, dbh, (10, 80), np.eye(3), seed=1)
    T_b_world = _planar(-35.0, 12.0, 37.0)
    b_xy, _, b_path, b_ids = _session(xy, dbh, (45, 115), T_b_world, seed=2)
    al = align_tree_maps(a_xy, b_xy, b_path)
    # A's frame is the world here: B's noise-free trees must land on the world's
    b_true = xy[b_ids] @ T_b_world[:2, :2].T + T_b_world[:2, 2]
    placed = b_true @ al.T_a_b[:2, :2].T + al.T_a_b[:2, 3]
    err = np.linalg.norm(placed - xy[b_ids], axis=1)
    assert err.mean() < 0.015 and err.max() < 0.05  # 3 cm noise per tree and session
    yaw = math.degrees(math.atan2(al.T_a_b[1, 0], al.T_a_b[0, 0]))
    assert abs(math.remainder(yaw + 37.0, 360.0)) < 0.1
    common = len(np.intersect1d(a_ids, b_ids))
    assert al.agreeing >= 2 and len(al.pairs) >= 0.95 * common
    assert np.array_equal(a_ids[al.pairs[:, 0]], b_ids[al.pairs[:, 1]])  # the same trees


def test_maps_of_different_stands_are_not_merged():
    xy, dbh = _stand(seed=0)
    other, odbh = _stand(seed=7)
    a_xy, *_ = _session(xy, dbh, (10, 80), np.eye(3), seed=1)
    b_xy, _, b_path, _ = _session(other, odbh, (10, 80), _planar(5, 5, 20), seed=2)
    with pytest.raises(InputError, match="could not be placed"):
        align_tree_maps(a_xy, b_xy, b_path)


def _write_run(run_dir, xy, dbh, path_xy):
    run_dir.mkdir()
    n = len(xy)
    write_trees_csv(
        run_dir / "trees.csv",
        {
            "id": np.arange(n),
            "x": xy[:, 0],
            "y": xy[:, 1],
            "z": np.full(n, 1.3),
            "dbh_m": dbh,
            "dbh_std_m": np.full(n, 0.01),
            "observations": np.full(n, 4),
        },
    )
    poses = np.tile(np.eye(4), (len(path_xy), 1, 1))
    poses[:, :2, 3] = path_xy
    write_tum(run_dir / "trajectory.tum", np.arange(len(path_xy)) * 0.1, poses)


def test_merge_command_writes_one_map_and_both_trajectories_in_a(tmp_path):
    from forestslam.cli.merge import register  # noqa: F401 - the command module imports

    xy, dbh = _stand()
    a_xy, a_dbh, a_path, a_ids = _session(xy, dbh, (10, 80), np.eye(3), seed=1)
    T_b_world = _planar(20.0, -4.0, -75.0)
    b_xy, b_dbh, b_path, b_ids = _session(xy, dbh, (45, 115), T_b_world, seed=2)
    _write_run(tmp_path / "a", a_xy, a_dbh, a_path)
    _write_run(tmp_path / "b", b_xy, b_dbh, b_path)
    summary = merge_runs(tmp_path / "a", tmp_path / "b", tmp_path / "m")
    merged = read_trees_csv(tmp_path / "m" / "trees.csv")
    both = merged["source"] == "both"
    common = np.intersect1d(a_ids, b_ids)
    assert summary["trees"]["both"] == both.sum() >= 0.95 * len(common)
    assert len(merged["x"]) == len(np.union1d(a_ids, b_ids)) + (len(common) - both.sum())
    assert np.all(merged["observations"][both] == 8)
    assert np.nanmax(np.abs(merged["dbh_std_m"][both] - 0.01 / math.sqrt(2))) < 1e-6
    _, poses_b = read_tum(tmp_path / "m" / "trajectory_b.tum")
    world = np.column_stack([np.linspace(45, 115, 60), np.full(60, 60.0)])
    assert np.abs(poses_b[:, :2, 3] - world).max() < 0.05  # B's path lands on the stand
    assert (tmp_path / "m" / "map.png").stat().st_size > 0
