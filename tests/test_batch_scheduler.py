"""`forestslam batch --scheduler`: `dask scheduler` and `dask worker` started here on 127.0.0.1
(random free ports, bounded waits, always stopped); a recording whose worker dies: one retry."""

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from forestslam.batch import load_manifest, run_batch

START_TIMEOUT_S = 90


def wait_for(condition, what: str, timeout_s: float = START_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"no {what} within {timeout_s} s")
        time.sleep(0.1)


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """Address of a scheduler with one single-threaded worker (worker deaths allowed: 1, as the
    LocalCluster of `forestslam batch` has it)."""
    from distributed import Client

    folder = tmp_path_factory.mktemp("dask")
    dask = Path(sys.executable).with_name("dask")
    env = dict(os.environ, DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="1")
    local = ["--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0", "--no-dashboard"]
    info = folder / "scheduler.json"
    log = open(folder / "dask.log", "w")  # noqa: SIM115 (closed below)
    procs = []

    def start(*args):  # own session: the worker's nanny and process end with it
        procs.append(
            subprocess.Popen(
                [str(dask), *args, *local], env=env, stdout=log, stderr=log, start_new_session=True
            )
        )

    try:
        start("scheduler", "--port", "0", "--scheduler-file", str(info))
        wait_for(lambda: info.is_file() and info.stat().st_size > 0, "scheduler file")
        address = json.loads(info.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        start(
            "worker",
            address,
            "--nworkers",
            "1",
            "--nthreads",
            "1",
            "--local-directory",
            str(folder / "worker"),
        )
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(1, timeout=START_TIMEOUT_S)
        yield address
    finally:
        for proc in reversed(procs):
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        log.close()


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    from forestslam.sim import simulate

    return simulate("sample", tmp_path_factory.mktemp("sim"), length_m=14.0)


def test_recordings_run_on_the_given_scheduler(scheduler, sequence, tmp_path):
    bag, truth = sequence / "sequence.bag", sequence / "truth"
    path = tmp_path / "manifest.yaml"
    path.write_text(
        "recordings:\n"
        f"  - {{name: short, input: {bag}, sensor: vlp16, truth: {truth}, max_scans: 10}}\n"
        "  - {name: absent, input: no-such.bag, sensor: vlp16}\n"
    )
    result = run_batch(load_manifest(path), tmp_path / "out", scheduler=scheduler, progress=False)
    with open(tmp_path / "out" / "summary.csv") as f:
        rows = {r["name"]: r for r in csv.DictReader(f)}
    assert rows["short"]["status"] == "ok" and int(rows["short"]["scans"]) == 10
    assert float(rows["short"]["ate_m"]) < 0.1
    assert rows["absent"]["status"] == "failed" and "file not found" in rows["absent"]["error"]
    assert [r["name"] for r in result.failed] == ["absent"]


def test_a_worker_that_dies_is_retried_once_then_failed(scheduler, sequence, tmp_path):
    """Kill the worker process whenever it runs the recording: after one retry it is failed."""
    from distributed import Client

    path = tmp_path / "manifest.yaml"
    path.write_text(
        f"recordings:\n  - {{name: doomed, input: {sequence / 'sequence.bag'}, sensor: vlp16}}\n"
    )
    kills = []
    done = threading.Event()

    def killer():
        with Client(scheduler, timeout="30s") as client:
            while not done.is_set():
                busy = [w for w, keys in client.processing().items() if keys]
                if busy and busy[0] not in [w for w, _ in kills]:
                    pid = client.run(os.getpid, workers=busy)[busy[0]]
                    os.kill(pid, signal.SIGKILL)  # the worker process the nanny started
                    kills.append((busy[0], pid))
                time.sleep(0.05)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    try:
        result = run_batch(
            load_manifest(path), tmp_path / "out", scheduler=scheduler, progress=False
        )
    finally:
        done.set()
        thread.join(timeout=30)
    (row,) = result.rows
    assert row["status"] == "failed" and "KilledWorker" in row["error"], row
    assert len(kills) == 2  # the first attempt and its one retry
