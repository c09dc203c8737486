"""The Rerun recording of a run holds what the viewer shows."""

from __future__ import annotations

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.viewer import RerunView


def test_saved_recording_holds_the_run_entities(tmp_path):
    rr = pytest.importorskip("rerun")
    path = tmp_path / "run.rrd"
    view = RerunView(save=path)
    rng = np.random.default_rng(1)
    poses = []
    for i in range(3):
        T = np.eye(4)
        T[0, 3] = i
        poses.append(T[:3, 3])
        view.scan(i, 0.1 * i, T, rng.normal(size=(50000, 3)))
        view.stems(i, 0.1 * i, rng.normal(size=(4, 3)), np.array([0.2, np.nan, 0.3, 0.25]))
        view.trajectory(i, 0.1 * i, np.array(poses))
    view.trees(2, 0.2, rng.normal(size=(10, 3)), np.full(10, 0.3))
    view.ground(2, 0.2, rng.normal(size=(100, 3)))
    view.close()
    assert path.stat().st_size > 1000
    summary = rr.chunk.RrdReader(path).store().summary()
    for entity in ("/world/scan", "/world/stems", "/world/trajectory", "/world/trees"):
        assert entity in summary


def test_viewer_needs_a_target():
    with pytest.raises(InputError, match="spawn"):
        RerunView()


def test_a_run_records_every_entity_as_it_goes(tmp_path):
    rr = pytest.importorskip("rerun")
    from forestslam.runner import run
    from forestslam.sim import simulate

    seq = simulate("sample", tmp_path / "sim", length_m=14.0)
    path = tmp_path / "run.rrd"
    run(
        seq / "sequence.bag",
        "vlp16",
        tmp_path / "run",
        mode="map3d",
        progress=False,
        rerun_save=path,
    )
    summary = rr.chunk.RrdReader(path).store().summary()
    for entity in ("scan", "stems", "trajectory", "trees", "ground", "sensor"):
        assert f"/world/{entity}" in summary
