"""One batch task without Dask: the adapter to the runner, prior_map, failed rows, errors."""

from pathlib import Path

from forestslam.batch import Recording
from forestslam.batch.job import one_line, process_recording
from forestslam.errors import InputError


class FakeSummary:
    scans, scans_per_s, trees = 7, 3.5, 2


def test_prior_map_and_settings_are_passed_to_a_runner_that_takes_them(tmp_path, monkeypatch):
    from forestslam import runner

    calls = []

    def run(input_path, sensor, out_dir, prior_map=None, **options):
        calls.append((input_path, sensor, Path(out_dir), prior_map, options))
        return FakeSummary()

    monkeypatch.setattr(runner, "run", run)
    rec = Recording(
        "a",
        tmp_path / "a.bag",
        "hdl32",
        mode="map3d",
        start=3,
        max_scans=9,
        prior_map=tmp_path / "stand.csv",
    )
    row = process_recording(rec, str(tmp_path / "out"))
    assert row["status"] == "ok" and (row["scans"], row["scans_per_s"], row["trees"]) == (7, 3.5, 2)
    ((input_path, sensor, out_dir, prior_map, options),) = calls
    assert (input_path, sensor, out_dir, prior_map) == (
        tmp_path / "a.bag",
        "hdl32",
        tmp_path / "out" / "a",
        tmp_path / "stand.csv",
    )
    assert options == dict(mode="map3d", config_path=None, start=3, max_scans=9, progress=False)
    assert (tmp_path / "out" / "a" / "batch.json").is_file()


def test_one_line_errors():
    assert one_line(InputError("x.bag: file not found\nmore")) == "x.bag: file not found"
    assert one_line(ValueError("bad value")) == "ValueError: bad value"
    assert one_line(MemoryError()) == "MemoryError"
