"""End to end: a short simulated VLP-16 loop through `forestslam run` and `evaluate`."""

import pytest

from forestslam.evaluation.report import evaluate_run
from forestslam.io import read_tum


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    from forestslam.sim import simulate

    out = tmp_path_factory.mktemp("sim")
    # the bundled `sample` stand, shortened to a 14 m loop (about 50 scans once the loop is
    # pushed clear of the stems)
    return simulate("sample", out, length_m=14.0)


def test_short_loop_slam_accuracy_and_trees(sequence, tmp_path):
    from forestslam.runner import run

    s = run(sequence / "sequence.bag", "vlp16", tmp_path, mode="slam", progress=False)
    n_truth = len(read_tum(sequence / "truth" / "trajectory.tum")[0])
    assert s.status == "complete" and s.scans == n_truth >= 40
    m = evaluate_run(tmp_path, sequence / "truth", max_dist_m=10.0, plot=False)
    assert m["trajectory"]["ate_rmse_m"] < 0.15
    t = m["trees"]
    assert t["recall"] >= 0.8, t
    assert t["precision"] >= 0.8, t
    assert t["dbh_mae_m"] < 0.05, t
