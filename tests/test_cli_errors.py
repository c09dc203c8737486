"""The CLI's error boundary (issue 19, items 5 and 9): an output path that is a file, any OSError,
a bad config or an unexpected exception is one line on stderr and a non-zero exit, never a
traceback unless `--debug`; `--version`; `simulate --list` without --out."""

from __future__ import annotations

import numpy as np
import pytest
from test_run import install_fake, make_input

import forestslam


@pytest.fixture
def scans(tmp_path, monkeypatch):
    install_fake(monkeypatch)
    return make_input(tmp_path, 6)[0]


def one_line_error(res, *needles: str) -> None:
    assert res.returncode == 1, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("forestslam: error:")]
    assert len(lines) == 1, res.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.mark.parametrize("inside", [False, True])
def test_output_path_that_is_a_file(tmp_path, scans, run_main, inside):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = blocker / "sub" if inside else blocker
    trees = tmp_path / "map.csv"
    trees.write_text("x,y\n0,0\n5,0\n0,5\n5,5\n")
    commands = {
        "run": ["run", scans, "--sensor", "vlp16", "--out", out, "--no-progress"],
        "localize": ["localize", scans, "--map", trees, "--sensor", "vlp16", "--out", out],
        "simulate": ["simulate", "--scenario", "sample", "--out", out],
        "detect": ["detect", scans, "--sensor", "vlp16", "--out", blocker / "trees.csv"],
        "tls-register": [
            "tls-register",
            scans,
            "--reference",
            scans / "000000.npy",
            "--sensor",
            "vlp16",
            "--out",
            out,
        ],
    }
    for args in commands.values():
        one_line_error(run_main(*args), str(blocker), "is a file")


def test_any_os_error_is_one_line_naming_the_path(tmp_path, scans, run_main, monkeypatch):
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / "out" / "run.yaml"))

    monkeypatch.setattr("forestslam.io.atomic.atomic_write_text", denied)
    res = run_main("run", scans, "--sensor", "vlp16", "--out", tmp_path / "out", "--no-progress")
    one_line_error(res, str(tmp_path / "out" / "run.yaml"), "Permission denied")


def test_unexpected_error_is_one_line_and_debug_shows_the_traceback(
    scans, tmp_path, run_main, monkeypatch
):
    def broken(self, scan):
        raise RuntimeError("a bug")

    monkeypatch.setattr("test_run.FakeOdometry.step", broken)
    args = ["run", scans, "--sensor", "vlp16", "--out", tmp_path / "o", "--no-progress"]
    res = run_main(*args)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "internal error: RuntimeError: a bug" in res.stderr and "--debug" in res.stderr
    with pytest.raises(RuntimeError, match="a bug"):  # --debug: the exception (traceback) out
        run_main("--debug", *args)


def test_bad_config_value_is_one_line(tmp_path, scans, run_main):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mapping:\n  dbh_window_scans: 0\n")
    res = run_main("run", scans, "--sensor", "vlp16", "--out", tmp_path / "o", "--config", cfg)
    one_line_error(res, "mapping.dbh_window_scans: 0", ">= 1")
    assert not (tmp_path / "o").exists()


def test_version(run_main):
    res = run_main("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"forestslam {forestslam.__version__}"


def test_simulate_list_needs_no_out(run_main):
    res = run_main("simulate", "--list")
    assert res.returncode == 0 and "sample" in res.stdout.split()
    one_line_error(run_main("simulate", "--scenario", "sample"), "--out")


def test_detect_scan_window_skips_without_decoding(tmp_path, run_main):
    """--scan K reads scan K only: an unreadable scan before it is never decoded."""
    folder = tmp_path / "scans"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(4):
        np.save(folder / f"{i:03d}.npy", rng.uniform(-10, 10, (200, 3)))
    (folder / "000.npy").write_bytes(b"garbage")
    out = tmp_path / "t.csv"
    res = run_main("detect", folder, "--scan", "2", "--sensor", "vlp16", "--out", out)
    assert res.returncode == 0, res.stderr
    assert "in 1 scan(s)" in res.stdout and "skipped" not in res.stderr
    res = run_main(
        "detect",
        folder,
        "--start",
        "1",
        "--max-scans",
        "2",
        "--sensor",
        "vlp16",
        "--out",
        out,
        "--no-progress",
    )
    assert res.returncode == 0 and "in 2 scan(s)" in res.stdout, res.stderr
    assert open(out).readline().startswith("scan,")  # several scans: a scan column
    assert {int(line.split(",")[0]) for line in open(out).readlines()[1:]} <= {1, 2}


def test_run_modes_are_choices(run_main, scans, tmp_path):
    from typing import get_args

    from forestslam.cli.run import Mode
    from forestslam.runner import MODES

    assert get_args(Mode) == MODES
    res = run_main("run", scans, "--sensor", "vlp16", "--out", tmp_path / "o", "--mode", "fly")
    assert res.returncode == 2 and "slam" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "o").exists()


def test_evaluate_warns_about_a_run_that_did_not_complete(tmp_path, run_main):
    from forestslam.job import Job

    scans_dir, truth = make_input(tmp_path, 5)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError), Job("run", out) as job:
        from forestslam.io import write_tum

        stamps, poses = np.arange(5) / 10.0, np.tile(np.eye(4), (5, 1, 1))
        write_tum(job.out / "odometry.tum", stamps, poses)
        raise RuntimeError("killed by a test")
    res = run_main("evaluate", out, "--truth", truth)
    assert res.returncode == 0, res.stderr
    assert "run.yaml says status: failed (RuntimeError: killed by a test)" in res.stderr


def test_a_binary_file_where_text_belongs_is_one_line(tmp_path, scans, run_main, monkeypatch):
    garbage = tmp_path / "map.csv"
    garbage.write_bytes(bytes(range(256)) * 4)
    args = ["run", scans, "--sensor", "vlp16", "--out", tmp_path / "o", "--no-progress"]
    one_line_error(run_main(*args, "--prior-map", garbage), str(garbage), "not UTF-8")
    profile = tmp_path / "p.yaml"
    profile.write_bytes(bytes(range(256)) * 4)
    one_line_error(run_main("run", scans, "--sensor", profile, "--out", tmp_path / "o"), "p.yaml")

    def undecodable(*args, **kwargs):  # any reader not yet wrapped: still one line, exit 1
        raise UnicodeDecodeError("utf-8", b"\x80", 0, 1, "invalid start byte")

    monkeypatch.setattr("forestslam.multisession.prior.load_prior_map", undecodable)
    one_line_error(run_main(*args, "--prior-map", garbage), "an input file is not UTF-8 text")


def _prior_map(path, offset=(0.0, 0.0), nan_rows=0):
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 60, (40, 2)) + offset
    xy[:nan_rows, 1] = np.nan
    rows = "".join(f"{x},{y},0.3\n" for x, y in xy)
    path.write_text("x,y,dbh_m\n" + rows)
    return path


def test_initial_pose_far_from_the_prior_map_is_refused(tmp_path, scans, run_main):
    utm = _prior_map(tmp_path / "utm.csv", offset=(500000.0, 6700000.0))
    args = ["run", scans, "--sensor", "vlp16", "--no-progress", "--prior-map", utm]
    res = run_main(*args, "--out", tmp_path / "o", "--initial-pose", "10,20,30")
    one_line_error(res, "--initial-pose 10,20,30", "from the nearest tree of the prior map")
    res = run_main(*args, "--out", tmp_path / "o2", "--initial-pose", "500010,6700020,30")
    assert res.returncode == 0, res.stderr


def test_prior_map_rows_without_coordinates_are_counted(tmp_path, scans, run_main, caplog):
    prior = _prior_map(tmp_path / "p.csv", nan_rows=4)
    res = run_main("run", scans, "--sensor", "vlp16", "--no-progress", "--out", tmp_path / "o",
                   "--prior-map", prior)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "4 rows without finite x, y ignored" in caplog.text


def test_detect_breast_height_outside_the_cloud_is_refused(tmp_path, run_main):
    """--breast-height-z 130 (cm for 1.3 m) measured 'stems' where the cloud has no points."""
    folder = tmp_path / "scans"
    folder.mkdir()
    np.save(folder / "000.npy", np.random.default_rng(0).uniform([-9, -9, -2], [9, 9, 8], (500, 3)))
    args = ["detect", folder, "--sensor", "vlp16", "--out", tmp_path / "t.csv"]
    one_line_error(run_main(*args, "--breast-height-z", "130"), "--breast-height-z 130", "z -2")
    assert not (tmp_path / "t.csv").exists()
    assert run_main(*args, "--breast-height-z", "1.3").returncode == 0
    one_line_error(run_main(*args, "--breast-height-z", "nan"), "must be a finite number")


@pytest.mark.parametrize("trees", [0, 2])
def test_localize_map_of_too_few_trees_is_refused(tmp_path, scans, run_main, trees):
    tree_map = tmp_path / "map.csv"
    tree_map.write_text("x,y\n" + "".join(f"{i * 5},0\n" for i in range(trees)))
    args = ["localize", scans, "--map", tree_map, "--sensor", "vlp16", "--out", tmp_path / "o"]
    one_line_error(run_main(*args), f"{trees} trees; localization needs 3 or more")


@pytest.mark.parametrize("drift", ["2,1", "-1,0", "0.02,1000"])
def test_inject_drift_out_of_range_is_refused(tmp_path, scans, run_main, drift):
    """`2,1` meant 2 %: a 200 % scale error is no test of anything, and -100 % stops the run."""
    args = ["run", scans, "--sensor", "vlp16", "--out", tmp_path / "o", "--inject-drift", drift]
    one_line_error(run_main(*args), f"--inject-drift {drift}", "fraction in (-1, 1)")


def test_prior_map_of_a_run_that_did_not_complete_is_warned(tmp_path, scans, run_main, caplog):
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    _prior_map(earlier / "trees.csv")
    (earlier / "run.yaml").write_text("command: run\nsummary:\n  status: failed\n  error: boom\n")
    res = run_main("run", scans, "--sensor", "vlp16", "--no-progress", "--out", tmp_path / "o",
                   "--prior-map", earlier)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "says status: failed (boom); using its last checkpoint" in caplog.text
