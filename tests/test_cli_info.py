"""`forestslam info`: text and JSON summaries, and bad input as one line with exit code 1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from forestslam.io import Scan, write_cloud, write_scans

ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """The real console entry in a new process (exit code, stderr, no traceback)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT / "python"), *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]]
    )
    return subprocess.run(
        [sys.executable, "-m", "forestslam.cli.main", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    rng = np.random.default_rng(4)
    scans = []
    for k in range(15):
        n = 800 + 10 * k
        points = rng.normal(0, 10, (n, 3))
        points[:5] = np.nan  # dropped: finite counts are n - 5
        ring = (np.arange(n) % 16).astype(np.uint16)
        time = np.full(n, 0.5)  # on the NaN points, which are dropped
        time[5:] = np.linspace(0.0, 0.099, n - 5)
        scans.append(Scan(50.0 + 0.1 * k, points, np.ones(n), ring, time))
    path = tmp_path_factory.mktemp("info") / "seq.bag"
    write_scans(path, scans)
    return path


def test_json(bag, run_main):
    result = run_main("info", str(bag), "--json")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    keys = ["format", "topics", "scans", "duration_s", "points_min", "points_median"]
    assert set(keys + ["points_max", "fields"]) <= set(info)
    assert info["format"] == "ros1" and info["scans"] == 15
    assert info["topics"] == [
        {"name": "/velodyne_points", "type": "sensor_msgs/msg/PointCloud2", "messages": 15}
    ]
    assert info["duration_s"] == pytest.approx(1.4, abs=1e-6)
    assert info["rate_hz"] == pytest.approx(10.0, abs=1e-4)
    assert (info["points_min"], info["points_median"], info["points_max"]) == (795, 865, 935)
    assert info["fields"]["ring"] == "uint16" and info["fields"]["x"] == "float32"
    assert info["rings"] == 16 and info["time_span_s"] == pytest.approx(0.099, abs=1e-6)


def test_text(bag, run_main):
    result = run_main("info", str(bag), "--topic", "/velodyne_points")
    assert result.returncode == 0, result.stderr
    assert "scans:    15" in result.stdout and "10.00 Hz" in result.stdout
    assert "min 795 / median 865 / max 935" in result.stdout


def test_cloud_folder(tmp_path, run_main):
    for k in range(3):
        write_cloud(tmp_path / f"{k:06d}.ply", np.arange(30, dtype=float).reshape(10, 3) + 1 + k)
    result = run_main("info", str(tmp_path), "--json", "--rate", "2")
    info = json.loads(result.stdout)
    assert info["format"] == "ply-folder" and info["scans"] == 3 and info["topics"] == []
    assert info["duration_s"] == pytest.approx(1.0) and info["points_max"] == 10


def _assert_one_line_error(result, *needles: str) -> None:
    assert result.returncode == 1
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("forestslam: error: ")
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in lines[0]


def test_errors_in_process(bag, tmp_path, run_main):
    _assert_one_line_error(run_main("info", str(tmp_path / "none.bag")), "none.bag", "not found")
    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(np.random.default_rng(1).bytes(5000))
    _assert_one_line_error(run_main("info", str(garbage)), "garbage.bag", "not a ROS1 bag")
    text = tmp_path / "a.csv"
    text.write_text("1,2\n")
    _assert_one_line_error(run_main("info", str(text)), "a.csv", "unsupported input type")
    _assert_one_line_error(run_main("info", str(bag), "--topic", "/nope"), "/nope", "/velodyne")


def test_error_from_console_process(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + np.random.default_rng(2).bytes(3000))
    _assert_one_line_error(run_cli("info", str(garbage)), "garbage.mcap")


def test_several_topics_need_topic(tmp_path, run_main):
    from rosbags.rosbag1 import Writer

    from forestslam.io.bags import POINTCLOUD2, _message, _typestore

    store = _typestore(True)
    path = tmp_path / "two.bag"
    with Writer(path) as writer:
        for topic in ("/a", "/b"):
            conn = writer.add_connection(topic, POINTCLOUD2, typestore=store)
            ns, msg = _message(store, True, Scan(1.0, np.ones((2, 3))), 0, "x")
            writer.write(conn, ns, store.serialize_ros1(msg, POINTCLOUD2))
    _assert_one_line_error(run_main("info", str(path)), "--topic", "/a (1 msgs)", "/b (1 msgs)")
    assert run_main("info", str(path), "--topic", "/b").returncode == 0


def test_truncated_bag_warns_and_reports(bag, tmp_path):
    data = bytearray(bag.read_bytes())
    i = data.index(b"index_pos=") + len(b"index_pos=")
    data[i : i + 8] = bytes(8)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bytes(data[: int(len(data) * 0.7)]))
    result = run_cli("info", str(cut), "--json")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert 5 <= info["scans"] < 15 and info["lost_bytes"] > 0
    assert "lost" in result.stderr  # the warning is logged
