"""`forestslam batch` on a 2-worker LocalCluster: short simulations, a corrupt bag, resume."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from forestslam.batch import load_manifest, run_batch


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    from forestslam.sim import simulate

    # the bundled `sample` stand on a 14 m loop: 127 VLP-16 scans with truth
    return simulate("sample", tmp_path_factory.mktemp("sim"), length_m=14.0)


def manifest(folder: Path, entries: list[str]) -> Path:
    path = folder / "manifest.yaml"
    path.write_text("recordings:\n" + "".join(f"  - {{{e}}}\n" for e in entries))
    return path


def read_summary(out: Path) -> dict[str, dict]:
    with open(out / "summary.csv") as f:
        return {row["name"]: row for row in csv.DictReader(f)}


def test_local_cluster_three_recordings_and_a_corrupt_one(sequence, tmp_path):
    bag, truth = sequence / "sequence.bag", sequence / "truth"
    rng = np.random.default_rng(20)
    (tmp_path / "corrupt.bag").write_bytes(rng.integers(0, 256, 100_000, dtype=np.uint8).tobytes())
    path = manifest(
        tmp_path,
        [
            # 40 scans (4 m of the loop): the evaluation's alignment of a 1.5 m straight piece
            # leaves its roll about the path free, which misplaces the far trees
            f"name: first, input: {bag}, sensor: vlp16, truth: {truth}, max_scans: 40",
            f"name: later, input: {bag}, sensor: vlp16, truth: {truth}, start: 20, max_scans: 40",
            "name: broken, input: corrupt.bag, sensor: vlp16",
            f"name: odo, input: {bag}, sensor: vlp16, mode: odometry, max_scans: 15",
        ],
    )
    out = tmp_path / "out"
    result = run_batch(load_manifest(path), out, workers=2, progress=False)

    rows = read_summary(out)
    assert list(rows) == ["first", "later", "broken", "odo"]  # manifest order
    assert [r["name"] for r in result.failed] == ["broken"]
    assert rows["broken"]["status"] == "failed"
    assert "not a ROS1 bag" in rows["broken"]["error"] and "\n" not in rows["broken"]["error"]
    for name in ("first", "later", "odo"):
        assert rows[name]["status"] == "ok" and rows[name]["error"] == ""
        expected = 15 if name == "odo" else 40
        assert int(rows[name]["scans"]) == expected and float(rows[name]["scans_per_s"]) > 0
        assert (out / name / "run.yaml").is_file() and (out / name / "batch.json").is_file()
    for name in ("first", "later"):  # evaluated against the simulator's truth
        metrics = json.loads((out / name / "metrics.json").read_text())
        assert float(rows[name]["ate_m"]) == pytest.approx(metrics["trajectory"]["ate_rmse_m"])
        assert float(rows[name]["ate_m"]) < 0.1
        for key in ("recall", "precision", "dbh_mae_m", "dbh_bias_m"):
            assert float(rows[name][key]) == pytest.approx(metrics["trees"][key])
        assert float(rows[name]["recall"]) >= 0.75 and float(rows[name]["precision"]) >= 0.75
        assert float(rows[name]["dbh_mae_m"]) < 0.05
        assert int(rows[name]["trees"]) > 0
    assert rows["odo"]["ate_m"] == "" and not (out / "odo" / "metrics.json").exists()
    md = (out / "summary.md").read_text()
    assert "3 of 4 recordings ok, 1 failed" in md and "| broken | failed |" in md
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # nothing left to do but the failed one: the finished three are kept as they are
    stamps = {n: (out / n / "batch.json").stat().st_mtime_ns for n in ("first", "later", "odo")}
    again = run_batch(load_manifest(path), out, workers=2, progress=False)
    assert again.skipped == 3 and [r["name"] for r in again.failed] == ["broken"]
    assert stamps == {n: (out / n / "batch.json").stat().st_mtime_ns for n in stamps}
    assert read_summary(out)["first"] == rows["first"]


CLI = [sys.executable, "-c", "from forestslam.cli.main import main; main()", "batch"]


def start_batch(path: Path, out: Path, interrupt: bool) -> subprocess.Popen:
    """`forestslam batch` with one worker in its own session (so the test can kill all of it)."""
    # Ctrl-C as a KeyboardInterrupt even where the test runs with SIGINT ignored (a background job)
    prefix = "import signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
    cmd = [*CLI, str(path), "--out", str(out), "--workers", "1"]
    if interrupt:
        cmd[2] = prefix + cmd[2]
    return subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, start_new_session=True)


def wait_until_started(proc: subprocess.Popen, run_dir: Path) -> None:
    deadline = time.monotonic() + 120
    while not (run_dir / "run.yaml").exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.02)


def three_recordings(folder: Path, bag: Path) -> Path:
    return manifest(
        folder,
        [
            f"name: one, input: {bag}, sensor: vlp16, max_scans: 10",
            f"name: two, input: {bag}, sensor: vlp16, max_scans: 40",
            f"name: three, input: {bag}, sensor: vlp16, max_scans: 10",
        ],
    )


def test_resume_after_an_interruption(sequence, tmp_path):
    """The whole batch killed while the second recording runs (kill -9, power loss): the next
    call keeps the first and redoes the second (left `status: running`) and the third."""
    path, out = three_recordings(tmp_path, sequence / "sequence.bag"), tmp_path / "out"
    proc = start_batch(path, out, interrupt=False)
    try:
        wait_until_started(proc, out / "two")  # one worker: `one` is finished
        os.killpg(proc.pid, signal.SIGKILL)  # the client, its scheduler and its worker at once
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    assert (out / "one" / "batch.json").is_file()
    assert not (out / "two" / "batch.json").exists()
    assert "status: running" in (out / "two" / "run.yaml").read_text()
    assert not (out / "three").exists() and not (out / "summary.csv").exists()
    kept = (out / "one" / "batch.json").stat().st_mtime_ns

    result = run_batch(load_manifest(path), out, workers=2, progress=False)
    assert result.skipped == 1 and not result.failed
    assert (out / "one" / "batch.json").stat().st_mtime_ns == kept
    rows = read_summary(out)
    assert [int(rows[n]["scans"]) for n in ("one", "two", "three")] == [10, 40, 10]
    assert "status: complete" in (out / "two" / "run.yaml").read_text()

    forced = run_batch(load_manifest(path), out, workers=2, force=True, progress=False)
    assert forced.skipped == 0 and not forced.failed
    assert (out / "one" / "batch.json").stat().st_mtime_ns > kept


def test_ctrl_c_stops_the_batch_with_status_130(sequence, tmp_path):
    path, out = three_recordings(tmp_path, sequence / "sequence.bag"), tmp_path / "out"
    proc = start_batch(path, out, interrupt=True)
    try:
        wait_until_started(proc, out / "two")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 130
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert "forestslam: interrupted; the same command resumes the batch" in proc.stderr.read()
    assert (out / "one" / "batch.json").is_file() and not (out / "summary.csv").exists()


def test_cli_exit_code_and_error_line(tmp_path):
    path = manifest(tmp_path, ["name: a, input: a.bag, sensor: vlp16, colour: red"])
    proc = subprocess.run(
        [*CLI, str(path), "--out", str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1].startswith("forestslam: error: ")
    assert "unknown key(s) colour" in proc.stderr and "Traceback" not in proc.stderr


def test_local_workers_run_with_glibc_default_memory_settings():
    """Dask's nanny would start workers with MALLOC_TRIM_THRESHOLD_=65536 (fixed mmap threshold:
    a recording then costs 8-9 % more CPU in page faults); the local cluster unsets it."""
    from forestslam.batch.engine import _client

    with _client(workers=1, scheduler=None, n_tasks=1) as client:
        env = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
    assert list(env.values()) == [None]
