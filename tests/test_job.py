"""The job skeleton (forestslam.job): output paths, the directory lock, an earlier run's outputs,
run.yaml's outcome, the scan window and progress in a log."""

from __future__ import annotations

import io
import os
import platform
import subprocess
import sys

import numpy as np
import pytest
import yaml

from forestslam.errors import InputError
from forestslam.job import (
    LOCK_NAME,
    Checkpoints,
    Job,
    Progress,
    ScanWindow,
    check_output_file,
    check_output_path,
)


def meta(out):
    return yaml.safe_load((out / "run.yaml").read_text())


def test_output_path_that_is_or_lies_in_a_file(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InputError, match=r"--out .*file: is a file, not a directory"):
        check_output_path(f)
    with pytest.raises(InputError, match=rf"--out .*file/a/b: {f} is a file"):
        check_output_path(f / "a" / "b")
    with pytest.raises(InputError, match=r"is a directory, not a file"):
        check_output_file(tmp_path)
    with pytest.raises(InputError, match=rf"trees.csv: {f} is a file"):
        check_output_file(f / "trees.csv")
    assert check_output_path(tmp_path / "new" / "dir").is_dir()


def test_run_yaml_records_each_outcome(tmp_path):
    with Job("run", tmp_path / "ok", {"input": "x"}) as job:
        assert meta(job.out)["summary"]["status"] == "running"
        (job.out / "trees.csv").write_text("id\n")
        job.summary = {"scans": 3}
    m = meta(tmp_path / "ok")
    assert m["command"] == "run" and m["input"] == "x"
    assert m["summary"] == {"scans": 3, "status": "complete"}
    assert m["outputs"] == ["run.yaml", "trees.csv"]
    assert not (tmp_path / "ok" / LOCK_NAME).exists()  # released

    with pytest.raises(ValueError), Job("run", tmp_path / "bad"):
        raise ValueError("no scan could be processed")
    m = meta(tmp_path / "bad")
    assert m["summary"]["status"] == "failed"
    assert m["summary"]["error"] == "ValueError: no scan could be processed"

    with pytest.raises(KeyboardInterrupt), Job("run", tmp_path / "int"):
        raise KeyboardInterrupt
    assert meta(tmp_path / "int")["summary"]["status"] == "interrupted"


def test_second_job_into_one_directory_fails_at_once(tmp_path):
    with Job("run", tmp_path) as first:
        busy = rf"in use by a running forestslam job \(pid {os.getpid()}"
        with pytest.raises(InputError, match=busy):
            Job("localize", tmp_path).__enter__()
        assert meta(first.out)["summary"]["status"] == "running"  # the second touched nothing
    with Job("run", tmp_path):  # free again
        pass


def test_lock_held_by_another_process_and_stale_lock_of_a_dead_one(tmp_path):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time\n"
            f"fd = os.open({str(tmp_path / LOCK_NAME)!r}, os.O_RDWR | os.O_CREAT)\n"
            "fcntl.flock(fd, fcntl.LOCK_EX)\n"
            "os.write(fd, b'pid %d, test holder' % os.getpid())\n"
            "print('locked', flush=True)\n"
            "sys.stdin.read()\n",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match=rf"pid {holder.pid}, test holder"):
            Job("run", tmp_path).__enter__()
    finally:
        holder.kill()  # dies holding the lock: the file stays, the lock goes
        holder.wait()
    assert (tmp_path / LOCK_NAME).read_text().startswith(f"pid {holder.pid}")
    with Job("run", tmp_path) as job:  # the stale lock is taken over
        assert f"pid {os.getpid()}" in (job.out / LOCK_NAME).read_text()


def test_rerun_removes_the_earlier_runs_outputs_and_keeps_other_files(tmp_path):
    with Job("run", tmp_path) as job:
        for name in ("trajectory.tum", "trees.csv", "map.png", "extra_from_a_plugin.las"):
            (job.out / name).write_text("old")
    (tmp_path / "notes.txt").write_text("mine")  # not written by forestslam
    with Job("run", tmp_path) as job:  # e.g. --mode odometry: writes odometry.tum only
        for name in ("trajectory.tum", "trees.csv", "map.png", "extra_from_a_plugin.las"):
            assert not (job.out / name).exists(), name
        (job.out / "odometry.tum").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "odometry.tum", "run.yaml"]
    assert meta(tmp_path)["outputs"] == ["odometry.tum", "run.yaml"]


def test_outputs_of_another_command_are_refused_unless_overwrite(tmp_path):
    with Job("run", tmp_path) as job:
        (job.out / "trajectory.tum").write_text("slam result")
    with pytest.raises(InputError, match=r"earlier `forestslam run` \(run.yaml, trajectory.tum\)"):
        Job("localize", tmp_path).__enter__()
    assert (tmp_path / "trajectory.tum").read_text() == "slam result"
    with Job("localize", tmp_path, overwrite=True):
        assert not (tmp_path / "trajectory.tum").exists()
    assert meta(tmp_path)["command"] == "localize"


def test_output_names_without_run_yaml_are_refused(tmp_path):
    (tmp_path / "trees.csv").write_text("a user's inventory")
    with pytest.raises(InputError, match=r"files of no forestslam run.yaml \(trees.csv\)"):
        Job("run", tmp_path).__enter__()
    assert (tmp_path / "trees.csv").read_text() == "a user's inventory"


def test_a_resumed_job_keeps_the_outputs_of_its_own_command_only(tmp_path):
    """A batch keeps an earlier batch's recording folders (it resumes them) and lists them in its
    run.yaml; the files of another command are still refused."""
    with Job("batch", tmp_path, resume=True) as job:
        (job.out / "rec0").mkdir()
        (job.out / "summary.csv").write_text("first")
    with Job("batch", tmp_path, resume=True) as job:
        assert (job.out / "rec0").is_dir() and (job.out / "summary.csv").read_text() == "first"
        (job.out / "rec1").mkdir()
    assert meta(tmp_path)["outputs"] == ["rec0", "rec1", "run.yaml", "summary.csv"]
    other = tmp_path / "other"
    with Job("run", other) as job:
        (job.out / "trees.csv").write_text("a run's map")
    with pytest.raises(InputError, match=r"earlier `forestslam run`"):
        Job("batch", other, resume=True).__enter__()


def test_an_input_among_the_outputs_to_replace_is_refused(tmp_path):
    with Job("tls-register", tmp_path) as job:
        (job.out / "plot.laz").write_text("merged cloud")
    with pytest.raises(InputError, match=r"the input .*plot.laz would be replaced"):
        Job("tls-register", tmp_path, inputs=[tmp_path / "plot.laz"]).__enter__()
    assert (tmp_path / "plot.laz").exists()


def test_scan_window_checks_and_counts():
    with pytest.raises(InputError, match="--start must be >= 0"):
        ScanWindow(-1)
    with pytest.raises(InputError, match="--max-scans must be >= 1"):
        ScanWindow(0, 0)
    assert ScanWindow(10, 5).count(100) == 5
    assert ScanWindow(98, 5).count(100) == 2
    assert ScanWindow(200).count(100) == 0
    assert ScanWindow(0, 7).count(None) == 7
    with pytest.raises(InputError, match=">= 1"):
        Checkpoints(0)
    every3 = Checkpoints(3)
    assert [n for n in (0, 1, 2, 3, 3, 3, 4, 5, 6, 7) if every3.due(n)] == [3, 6]


def test_scan_window_skips_without_decoding(tmp_path):
    """Scans before --start are never read: a corrupt one there costs nothing."""
    for i in range(6):
        np.save(tmp_path / f"{i:03d}.npy", np.full((20, 3), float(i + 1)))
    (tmp_path / "001.npy").write_bytes(b"not a numpy file")
    stream, scans, count = ScanWindow(2, 3).open(tmp_path)
    got = [float(s.points[0, 0]) for s in scans]
    assert got == [3.0, 4.0, 5.0] and count == 3
    assert stream.stats.skipped == 0


def test_progress_in_a_log_is_one_line_every_few_seconds(monkeypatch):
    log = io.StringIO()  # not a terminal
    clock = iter(np.arange(0.0, 100.0, 0.5))  # 0.5 s per update
    monkeypatch.setattr("forestslam.job.time.monotonic", lambda: float(next(clock)))
    bar = Progress(60, "scan", "run", interval_s=10.0, stream=log)
    for _ in range(60):
        bar.update(1, trees=4)
    bar.close()
    lines = log.getvalue().splitlines()
    assert 2 <= len(lines) <= 4, lines  # 30 s of updates: every 10 s, and the last
    assert lines[-1].startswith("run: 60/60 scans") and lines[-1].endswith("trees 4")
    quiet = io.StringIO()
    bar = Progress(5, enabled=False, stream=quiet)
    bar.update(5)
    bar.close()
    assert quiet.getvalue() == ""


def test_a_foreign_run_yaml_is_not_taken_for_an_earlier_run(tmp_path):
    (tmp_path / "run.yaml").write_text("my: own settings\n")
    (tmp_path / "a").write_text("keep")
    with pytest.raises(InputError, match=r"files of no forestslam run.yaml \(run.yaml\)"):
        Job("run", tmp_path).__enter__()
    assert (tmp_path / "run.yaml").read_text() == "my: own settings\n"
    # a damaged `outputs` list of an earlier run.yaml names nothing to remove
    (tmp_path / "run.yaml").write_text("command: run\nsummary: {status: complete}\noutputs: a\n")
    with Job("run", tmp_path):
        assert (tmp_path / "a").read_text() == "keep"


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
def test_a_job_keeps_freed_memory_for_reuse_on_glibc(tmp_path):
    """The tuning is applied (mallopt accepted both settings), and a job still runs after it."""
    from forestslam.job import keep_freed_memory

    assert keep_freed_memory()
    with Job("run", tmp_path / "out") as job:
        job.summary = {"scans": 1}
    assert meta(tmp_path / "out")["summary"]["status"] == "complete"
