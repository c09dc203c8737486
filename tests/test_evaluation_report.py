"""`forestslam evaluate` on hand-made run and truth directories."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.evaluation.report import evaluate_run, format_table
from forestslam.io import write_trees_csv, write_tum

REPO = Path(__file__).resolve().parents[1]


def line_poses(xs, dy=0.0):
    poses = np.tile(np.eye(4), (len(xs), 1, 1))
    poses[:, 0, 3] = xs
    poses[:, 1, 3] = dy
    return poses


@pytest.fixture
def dirs(tmp_path):
    truth, run = tmp_path / "truth", tmp_path / "run"
    stamps = np.arange(21) * 0.1
    write_tum(truth / "trajectory.tum", stamps, line_poses(np.arange(21.0), dy=5.0))
    write_trees_csv(
        truth / "trees.csv",
        {
            "id": np.arange(3),
            "x": np.array([2.0, 10.0, 18.0]),
            "y": np.array([8.0, 1.0, 8.0]),
            "z_ground": np.zeros(3),
            "dbh_m": np.array([0.3, 0.2, 0.25]),
            "height_m": np.full(3, 20.0),
        },
    )
    # estimate in the first scan's frame: the truth shifted by (0, -5); 10 % too long
    write_tum(run / "trajectory.tum", stamps, line_poses(1.1 * np.arange(21.0)))
    write_tum(run / "odometry.tum", stamps, line_poses(1.2 * np.arange(21.0)))
    write_trees_csv(
        run / "trees.csv",
        {
            "id": np.arange(2),
            "x": np.array([2.0 + 1.0, 10.0 + 1.0]),
            "y": np.array([3.1, -4.0]),
            "z": np.array([1.3, 1.3]),
            "dbh_m": np.array([0.32, 0.19]),
            "dbh_std_m": np.full(2, 0.01),
            "observations": np.array([5, 5]),
        },
    )
    return run, truth


def test_evaluate_run_metrics(dirs):
    run, truth = dirs
    m = evaluate_run(run, truth)
    assert m["trajectory"]["ate_rmse_m"] == pytest.approx(0.1 * np.sqrt(770 / 21), abs=1e-6)
    assert m["trajectory"]["rpe_percent_10m"] == pytest.approx(10.0, abs=1e-6)
    assert m["odometry"]["final_drift_m"] == pytest.approx(4.0, abs=1e-6)
    # alignment: translation (-1, 5) (centroids 11 -> 10), identity rotation
    t = m["trees"]
    assert t["n_truth"] == 3 and t["n_est"] == 2 and t["n_matched"] == 2
    assert t["recall"] == pytest.approx(2 / 3)
    assert t["precision"] == 1.0
    assert t["mean_position_error_m"] == pytest.approx(0.05, abs=1e-6)  # 0.1 and 0
    assert t["dbh_bias_m"] == pytest.approx(0.005, abs=1e-9)
    assert (run / "metrics.json").is_file() and (run / "errors.png").stat().st_size > 1000
    on_disk = json.loads((run / "metrics.json").read_text())
    assert on_disk["trees"]["n_matched"] == 2
    table = format_table(m)
    assert "ATE RMSE" in table and "tree recall" in table and "DBH MAE" in table


def test_evaluate_cli_prints_table_and_fails_cleanly(dirs, tmp_path):
    run, truth = dirs
    path = [str(REPO / "python")] + os.environ.get("PYTHONPATH", "").split(os.pathsep)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in path if p))
    cmd = [sys.executable, "-m", "forestslam.cli.main", "evaluate", str(run), "--truth"]
    ok = subprocess.run(cmd + [str(truth)], capture_output=True, text=True, env=env)
    assert ok.returncode == 0, ok.stderr
    assert "tree precision" in ok.stdout
    bad = subprocess.run(cmd + [str(tmp_path / "nowhere")], capture_output=True, text=True, env=env)
    assert bad.returncode == 1
    assert "trajectory.tum" in bad.stderr and "Traceback" not in bad.stderr


def test_evaluate_run_without_trajectory_is_input_error(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "truth").mkdir()
    write_tum(tmp_path / "truth" / "trajectory.tum", np.zeros(1), np.eye(4)[None])
    with pytest.raises(InputError):
        evaluate_run(tmp_path / "run", tmp_path / "truth")
