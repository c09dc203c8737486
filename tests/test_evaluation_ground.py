"""DTM and ground-map evaluation against the simulator's terrain, with known answers."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from forestslam.evaluation.ground import dtm_cells, height_errors, load_truth_terrain
from forestslam.evaluation.report import evaluate_run, format_table
from forestslam.io import write_tum
from forestslam.mapping import dtm_grid, write_dtm

REPO = Path(__file__).resolve().parents[1]


class Plane:
    """z = 0.1 x - 0.05 y + 2 (the `height_at` of a terrain)."""

    def height_at(self, xy):
        xy = np.asarray(xy).reshape(-1, 2)
        return 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 2.0


def rigid(yaw, t):
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = t
    return T


def test_height_errors_in_the_truth_frame():
    rng = np.random.default_rng(3)
    T_truth_est = rigid(0.7, [5.0, -3.0, 1.0])
    world = np.c_[rng.uniform(-20, 20, (500, 2)), np.zeros(500)]
    world[:, 2] = Plane().height_at(world[:, :2]) + 0.04  # a DTM 4 cm too high everywhere
    world[:10, 2] += 1.0  # and ten cells on a log
    est = (world - T_truth_est[:3, 3]) @ T_truth_est[:3, :3]  # the same points, estimate frame
    e = height_errors(est, T_truth_est, Plane())
    assert e["n"] == 500
    assert e["median_abs_m"] == pytest.approx(0.04, abs=1e-9)
    assert e["bias_m"] == pytest.approx(0.04, abs=1e-9)
    assert e["rmse_m"] == pytest.approx(np.sqrt((490 * 0.04**2 + 10 * 1.04**2) / 500), rel=1e-9)
    # Without the alignment the same points are wrong by metres: the transform is applied.
    assert height_errors(est, np.eye(4), Plane())["median_abs_m"] > 0.3
    assert height_errors(np.zeros((0, 3)), np.eye(4), Plane())["n"] == 0


def test_dtm_cells_follow_the_written_grid(tmp_path):
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 10, (4000, 2))
    pts = np.c_[xy, Plane().height_at(xy)]
    write_dtm(tmp_path, dtm_grid(pts, cell_m=0.5))
    cells = dtm_cells(tmp_path / "dtm.npz")
    assert len(cells) > 300
    # Each cell holds the mean of a plane over the cell: its centre's height.
    np.testing.assert_allclose(cells[:, 2], Plane().height_at(cells[:, :2]), atol=0.02)


def test_no_terrain_without_a_scenario(tmp_path):
    assert load_truth_terrain(tmp_path) is None


def test_evaluate_reports_the_dtm_against_the_simulated_terrain(tmp_path):
    truth, run = tmp_path / "truth", tmp_path / "run"
    truth.mkdir()
    shutil.copy(REPO / "data" / "sample.yaml", truth / "scenario.yaml")
    terrain = load_truth_terrain(truth)
    a = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    gt = np.tile(np.eye(4), (60, 1, 1))
    gt[:, 0, 3], gt[:, 1, 3] = 10 * np.cos(a), 6 * np.sin(a)
    gt[:, 2, 3] = terrain.height_at(gt[:, :2, 3]) + 1.0
    T_truth_est = rigid(-0.4, [2.0, 1.0, 0.5])
    stamps = np.arange(60) * 0.1
    write_tum(truth / "trajectory.tum", stamps, gt)
    write_tum(run / "trajectory.tum", stamps, np.linalg.inv(T_truth_est) @ gt)
    # The run's DTM: the true terrain 3 cm high, on a grid in the estimate frame.
    gx, gy = np.meshgrid(np.arange(-12, 12, 0.25), np.arange(-8, 8, 0.25))
    world = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    world[:, 2] = terrain.height_at(world[:, :2]) + 0.03
    est = (world - T_truth_est[:3, 3]) @ T_truth_est[:3, :3]
    write_dtm(run, dtm_grid(est, cell_m=0.5))
    m = evaluate_run(run, truth, plot=False)
    assert m["trajectory"]["ate_rmse_m"] < 1e-6
    dtm = m["ground"]["dtm"]
    assert dtm["n"] > 1000
    # Cell means of a smooth terrain (0.5 m relief over 50 m): within 1 cm of +3 cm.
    assert dtm["bias_m"] == pytest.approx(0.03, abs=0.01)
    assert dtm["p90_abs_m"] < 0.05
    assert "DTM vs terrain" in format_table(m)
