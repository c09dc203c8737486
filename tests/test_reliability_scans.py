"""Silent degradations of decoded scans, on scans of the simulated sample sequence: each is
warned once and counted in the reader's stats (run.yaml `read_stats.degraded`), never passed on
silently (see forestslam.io.checks)."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from sim_bags import sample_sequence

from forestslam.errors import InputError
from forestslam.io import Scan, read_scans, write_cloud, write_scans
from forestslam.io.checks import MAX_POINT_TIME_S, check_scan
from forestslam.io.fields import scan_from_structured
from forestslam.io.source import ReadStats


@pytest.fixture(scope="module")
def sim_scans() -> list[Scan]:
    return list(read_scans(sample_sequence("bag")))[:6]


def _round_trip(tmp_path, scans: list[Scan]):
    path = tmp_path / "mutated.bag"
    write_scans(path, scans)
    stream = read_scans(path)
    return list(stream), stream.stats


def test_simulated_scans_pass_unchanged(sim_scans, tmp_path):
    out, stats = _round_trip(tmp_path, sim_scans)
    assert len(out) == len(sim_scans) and stats.degraded == {} and stats.warnings == []
    assert all(s.time is not None and s.ring is not None for s in out)


def test_absurd_per_point_time_is_ignored_not_deskewed(sim_scans, tmp_path, caplog):
    """A per-point time of 1e20 was taken for float nanoseconds since the epoch: 1e11 s reached
    the deskewing, the odometry blew up and the back end failed (issue 19, item 4)."""
    bad = [dataclasses.replace(s) for s in sim_scans]
    bad[2].time = np.full(len(bad[2]), 1e20)
    bad[4].time = bad[4].time.copy()
    bad[4].time[::7] = 5.0  # 5 s into a 0.1 s sweep
    out, stats = _round_trip(tmp_path, bad)
    assert [s.time is None for s in out] == [False, False, True, False, True, False]
    assert stats.degraded == {"time_ignored": 2}
    assert "time field ignored, scan not deskewed" in caplog.text
    assert caplog.text.count("time field ignored") == 1  # warned once, counted twice
    from forestslam.cli.info import summarize

    assert summarize(tmp_path / "mutated.bag", None, 10.0)["degraded"] == {"time_ignored": 2}


@pytest.mark.parametrize(
    ("times", "kept"),
    [
        (np.linspace(0.0, 0.099, 20), True),  # Velodyne: float seconds from the stamp
        (np.arange(20, dtype=np.uint32) * 5_000_000, True),  # Ouster: uint32 ns from the stamp
        (1_600_000_000_000_000_000 + np.arange(20, dtype=np.uint64) * 5_000_000, True),  # epoch ns
        (1.6e18 + np.arange(20) * 5e6, True),  # Livox ROS2: float64 ns since the epoch
        (1.6e9 + np.arange(20) * 0.005, True),  # Hesai: float seconds since the epoch
        (np.full(20, 1e20), False),
        (np.r_[np.linspace(0.0, 0.09, 19), np.nan], False),
        (np.linspace(0.0, 3.0, 20), False),  # 3 s: not within one sweep
    ],
)
def test_per_point_time_conventions(sim_scans, times, kept):
    scan = sim_scans[0]
    arr = np.zeros(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("t", times.dtype)])
    for k, c in enumerate("xyz"):
        arr[c] = scan.points[:20, k]
    arr["t"] = times
    stamp = 1.6e9 if kept and times.max() > 1e6 else None
    stats = ReadStats()
    out = check_scan(scan_from_structured(arr, stamp, "test"), stats, "test")
    assert (out.time is not None) == kept
    if kept:
        assert np.abs(out.time).max() <= MAX_POINT_TIME_S
        np.testing.assert_allclose(
            np.diff(out.time),
            np.diff(times.astype(float))
            * (1e-9 if times.max() > 1e12 or times.dtype.kind in "iu" else 1.0),
            atol=1e-6,
        )


def test_scans_without_usable_points_are_skipped_and_counted(sim_scans, tmp_path, caplog):
    """They were given poses at the origin and counted as processed."""
    bad = [dataclasses.replace(s) for s in sim_scans]
    n = len(bad[1])
    bad[1] = Scan(bad[1].stamp, np.full((n, 3), np.nan))
    bad[3] = Scan(bad[3].stamp, np.zeros((n, 3)))  # "no return" everywhere
    bad[4] = bad[4].select(np.arange(5))
    out, stats = _round_trip(tmp_path, bad)
    assert [s.stamp for s in out] == [bad[k].stamp for k in (0, 2, 5)]
    assert stats.degraded["empty_scans"] == 3 and stats.scans == 3 and stats.messages == 6
    assert "fewer than 10: scan skipped" in caplog.text


@pytest.mark.parametrize(("scale", "unit"), [(1000.0, "millimetres"), (100.0, "centimetres")])
def test_coordinates_in_mm_or_cm_are_detected(sim_scans, tmp_path, caplog, scale, unit):
    """They gave 0 trees with no hint."""
    bad = [dataclasses.replace(s, points=s.points * scale) for s in sim_scans]
    out, stats = _round_trip(tmp_path, bad)
    assert len(out) == len(bad)  # kept: the warning says what to do
    assert stats.degraded == {"implausible_range": len(bad)}
    assert f"are the coordinates in {unit}?" in caplog.text


def test_all_zero_ring_is_treated_as_missing(sim_scans, tmp_path, caplog):
    """It was trusted: every point on ring 0 cut the stem detection by 70 %."""
    bad = [dataclasses.replace(s, ring=np.zeros(len(s), np.uint16)) for s in sim_scans]
    bad[0] = sim_scans[0]  # a real ring field stays
    out, stats = _round_trip(tmp_path, bad)
    assert out[0].ring is not None and all(s.ring is None for s in out[1:])
    assert stats.degraded == {"ring_ignored": len(bad) - 1}
    assert "ring field is 0 on every point" in caplog.text


def test_kitti_bin_of_wrong_size_is_rejected(sim_scans, tmp_path):
    """A .bin whose size is not a multiple of 16 bytes was read, dropping the partial float."""
    folder = tmp_path / "velodyne"
    for k, scan in enumerate(sim_scans[:3]):
        write_cloud(folder / f"{k:06d}.bin", scan.points, scan.intensity)
    odd = folder / "000001.bin"
    odd.write_bytes(odd.read_bytes() + b"\0\0\0")  # whole floats a multiple of 4: was accepted
    stream = read_scans(folder)
    assert len(list(stream)) == 2 and stream.stats.skipped == 1
    assert "not a multiple of 16" in stream.stats.warnings[0]
    with pytest.raises(InputError, match="000001.bin.*multiple of 16"):
        list(read_scans(odd))


def test_symlink_loop_is_reported_as_such(tmp_path):
    """It was reported as 'file not found'."""
    os.symlink(tmp_path / "b.bag", tmp_path / "a.bag")
    os.symlink(tmp_path / "a.bag", tmp_path / "b.bag")
    with pytest.raises(InputError, match="a.bag: symbolic link loop"):
        read_scans(tmp_path / "a.bag")
    os.symlink(tmp_path / "gone.bag", tmp_path / "c.bag")
    with pytest.raises(InputError, match="dangling symbolic link"):
        read_scans(tmp_path / "c.bag")
    with pytest.raises(InputError, match="file not found"):
        read_scans(tmp_path / "d.bag")
