"""`forestslam merge` as a careless user calls it: the same run twice, a run still running or
killed, --out onto an input run, a binary trees.csv: one line and a non-zero exit, or a warning;
its --out is owned as a job (run.yaml with status complete)."""

from __future__ import annotations

import fcntl
import os
import shutil

import numpy as np
import pytest
import yaml
from test_cli_errors import one_line_error

from forestslam.io import write_trees_csv, write_tum


def _run_dir(path, seed=0, status=None):
    """A run directory: 40 trees on a 60 m square, a straight path through them."""
    rng = np.random.default_rng(seed)
    path.mkdir()
    grid = np.stack(np.meshgrid(np.arange(8), np.arange(5)), -1).reshape(-1, 2) * 7.5
    xy = grid + rng.uniform(-2, 2, grid.shape)
    n = len(xy)
    write_trees_csv(
        path / "trees.csv",
        {"id": np.arange(n), "x": xy[:, 0], "y": xy[:, 1], "z": np.full(n, 1.3),
         "dbh_m": rng.uniform(0.15, 0.4, n), "dbh_std_m": np.full(n, 0.01),
         "observations": np.full(n, 4)},
    )  # fmt: skip
    poses = np.tile(np.eye(4), (30, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3] = np.linspace(0, 50, 30), 15.0
    write_tum(path / "trajectory.tum", np.arange(30) * 0.1, poses)
    if status:
        doc = {"command": "run", "summary": {"status": status}}
        (path / "run.yaml").write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture
def runs(tmp_path):
    a = _run_dir(tmp_path / "a", status="complete")
    b = tmp_path / "b"
    shutil.copytree(a, b)
    return a, b


def test_two_copies_of_one_run_merge_onto_each_other(runs, tmp_path, run_main):
    res = run_main("merge", *runs, "--out", tmp_path / "m")
    assert res.returncode == 0, res.stderr
    meta = yaml.safe_load((tmp_path / "m" / "run.yaml").read_text())
    assert meta["command"] == "merge" and meta["summary"]["status"] == "complete"
    assert abs(meta["summary"]["x"]) < 1e-6 and "trees.csv" in meta["outputs"]
    merged = yaml.safe_load((tmp_path / "m" / "merge.yaml").read_text())
    assert merged["trees"]["merged"] == merged["trees"]["both"] == 40


def test_the_same_run_twice_is_refused(runs, tmp_path, run_main):
    one_line_error(run_main("merge", runs[0], runs[0], "--out", tmp_path / "m"), "same directory")


def test_out_onto_an_input_run_never_replaces_it(runs, run_main):
    a, b = runs
    before = (a / "trees.csv").read_bytes()
    one_line_error(run_main("merge", a, b, "--out", a), "--overwrite")
    one_line_error(run_main("merge", a, b, "--out", a, "--overwrite"), "would be replaced")
    assert (a / "trees.csv").read_bytes() == before


def test_a_run_still_running_is_refused_a_killed_one_warned(runs, tmp_path, run_main, caplog):
    a, b = runs
    (b / "run.yaml").write_text(
        yaml.safe_dump({"command": "run", "summary": {"status": "running"}})
    )
    fd = os.open(b / ".forestslam.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a live job holds its lock
    try:
        one_line_error(run_main("merge", a, b, "--out", tmp_path / "m"), "still running")
    finally:
        os.close(fd)
    res = run_main("merge", a, b, "--out", tmp_path / "m")  # killed: lock free, checkpoint kept
    assert res.returncode == 0 and "says status: running" in caplog.text


@pytest.mark.parametrize("which", ["trees.csv", "trajectory.tum"])
def test_a_binary_input_file_is_one_line(runs, tmp_path, run_main, which):
    (runs[1] / which).write_bytes(bytes(range(256)) * 8)
    one_line_error(run_main("merge", *runs, "--out", tmp_path / "m"), str(runs[1] / which))


def test_a_missing_run_names_it(runs, tmp_path, run_main):
    one_line_error(run_main("merge", runs[0], tmp_path / "nope", "--out", tmp_path / "m"), "nope")
