"""`forestslam run` owns its output directory (issue 19, item 7): a re-run leaves no stale
outputs, a failed re-run says `failed`, two runs into one directory cannot mix. The odometry is
the test double of tests/test_run.py."""

from __future__ import annotations

import pytest
import yaml
from test_run import install_fake, make_input

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
