"""`forestslam run` owns its output directory (issue 19, item 7): a re-run leaves no stale
outputs, a failed re-run says `failed`, two runs into one directory cannot mix. The odometry is
the test double of tests/test_run.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
import yaml
from test_run import REPO, install_fake, make_input

from forestslam.errors import InputError
from forestslam.io import read_tum
from forestslam.job import Job


def status(out):
    return yaml.safe_load((out / "run.yaml").read_text())["summary"]


def test_rerun_in_another_mode_leaves_no_stale_outputs(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 30)
    out = tmp_path / "out"
    run(scans, "vlp16", out, mode="slam", progress=False)
    assert (out / "trajectory.tum").is_file() and (out / "trees.csv").is_file()
    run(scans, "vlp16", out, mode="odometry", progress=False, max_scans=10)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["odometry.tum", "run.yaml", "timing.json"]  # no trajectory/trees/map
    assert len(read_tum(out / "odometry.tum")[0]) == 10
    meta = yaml.safe_load((out / "run.yaml").read_text())
    assert meta["mode"] == "odometry" and meta["outputs"] == names


def test_failed_rerun_records_failed_with_the_error(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 12)
    out = tmp_path / "out"
    run(scans, "vlp16", out, progress=False)
    with pytest.raises(InputError, match="no scan could be processed"):
        run(scans, "vlp16", out, start=50, progress=False)  # an empty window
    s = status(out)
    assert s["status"] == "failed" and "no scan could be processed" in s["error"]
    assert s["scans"] == 0
    assert not (out / "trajectory.tum").exists()  # the earlier run's outputs are gone


def test_a_second_run_into_a_busy_directory_fails_at_once(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 12)
    out = tmp_path / "out"
    with Job("run", out):  # a run in progress
        with pytest.raises(InputError, match="in use by a running forestslam job"):
            run(scans, "vlp16", out, progress=False)
        assert not (out / "odometry.tum").exists()


def test_a_run_does_not_replace_another_commands_outputs(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 12)
    out = tmp_path / "loc"
    with Job("localize", out) as job:
        (job.out / "localization.json").write_text("{}")
    with pytest.raises(InputError, match=r"earlier `forestslam localize`.*--overwrite"):
        run(scans, "vlp16", out, progress=False)
    assert (out / "localization.json").is_file()
    run(scans, "vlp16", out, progress=False, overwrite=True)
    assert not (out / "localization.json").exists() and status(out)["status"] == "complete"


def test_bad_config_object_is_refused_before_the_directory_is_touched(tmp_path, monkeypatch):
    from forestslam.config import ForestSlamConfig
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 5)
    cfg = ForestSlamConfig()
    cfg.mapping.checkpoint_every_scans = 0  # was silently treated as 1
    with pytest.raises(InputError, match=r"mapping.checkpoint_every_scans: 0"):
        run(scans, "vlp16", tmp_path / "out", config=cfg, progress=False)
    assert not (tmp_path / "out").exists()


SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from test_run import install_fake
install_fake(delay_s=0.02)
from forestslam.cli.main import main
sys.argv = ["forestslam", "run", {scans!r}, "--sensor", "vlp16", "--out", {out!r},
            "--mode", "odometry", "--no-progress"]
main()
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stopped_run_says_interrupted(tmp_path, sig):
    scans, _ = make_input(tmp_path, 400)  # 8 s at 0.02 s per scan: stopped long before
    out = tmp_path / "out"
    script = SCRIPT.format(tests=str(REPO / "tests"), scans=str(scans), out=str(out))
    path = [str(REPO / "python")] + os.environ.get("PYTHONPATH", "").split(os.pathsep)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in path if p))
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, stderr=subprocess.PIPE)
    deadline = time.time() + 60
    while time.time() < deadline and not (out / "run.yaml").is_file():
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    assert proc.returncode == 128 + sig, err[-3000:]
    assert "forestslam: interrupted" in err and "Traceback" not in err
    s = status(out)
    assert s["status"] == "interrupted" and 0 < s["scans"] < 400
    assert len(read_tum(out / "odometry.tum")[0]) == s["scans"]  # final outputs written
