"""Fuzzing the readers with seeded mutations of simulated bags: whole files (bit flips, garbage,
cuts, inserted, deleted and repeated ranges, aimed at random bytes and at record headers) and
PointCloud2 fields (layout, field list, data). Through `forestslam info` (in this process, and
in a new one for a few) and `read_scans`: no traceback, no crash, no hang (30 s per input)."""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from sim_bags import sample_sequence

from forestslam.errors import InputError
from forestslam.io import read_scans

HANG_S = 30
BAG_MUTATIONS = 160  # per format: ~0.05 s each
FIELD_BAGS, MESSAGES_PER_BAG = 16, 10


class Hang(Exception):
    pass


@contextlib.contextmanager
def deadline(seconds: float):
    def alarm(signum, frame):
        raise Hang(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def info_in_process(path: Path, capsys) -> tuple[int, str]:
    """`forestslam info PATH --json` through the CLI's own main: (exit code, stderr)."""
    from forestslam.cli.main import main

    old = sys.argv
    sys.argv = ["forestslam", "-q", "info", str(path), "--json"]
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code
    finally:
        sys.argv = old
    return code, capsys.readouterr().err


def check_input(path: Path, capsys, what: str) -> str:
    """Read one input both ways; returns 'read', 'error' (a clean InputError)."""
    with deadline(HANG_S):
        code, err = info_in_process(path, capsys)
        assert code in (0, 1), (what, code, err)
        assert "Traceback" not in err, (what, err)
        if code == 1:
            assert err.strip().splitlines()[-1].startswith("forestslam: error: "), (what, err)
        try:
            stream = read_scans(path)
        except InputError:
            return "error"
        for scan in stream:
            assert np.isfinite(scan.points).all() and len(scan) >= 10, what
            assert scan.time is None or np.abs(scan.time).max() <= 1.0, what
    return "read"


def _anchors(data: bytes) -> np.ndarray:
    """Byte offsets of record headers (ROS1 `op=` fields, MCAP chunk opcodes)."""
    marks = [i for pat in (b"op=", b"\x06") for i in _find_all(data, pat)][:5000]
    return np.asarray(marks or [0])


def _find_all(data: bytes, pattern: bytes, limit: int = 5000) -> list[int]:
    out, i = [], data.find(pattern)
    while i >= 0 and len(out) < limit:
        out.append(i)
        i = data.find(pattern, i + 1)
    return out


def mutate(data: bytes, rng: np.random.Generator, anchors: np.ndarray) -> tuple[bytes, str]:
    """One seeded mutation of a whole file; returns it and what it was."""
    out = bytearray(data)
    n = len(out)
    near = int(anchors[rng.integers(len(anchors))]) + int(rng.integers(-64, 64))
    at = int(np.clip(near if rng.random() < 0.5 else rng.integers(n), 0, n - 1))
    kind = ["flip", "garbage", "cut", "insert", "delete", "repeat", "zero"][rng.integers(7)]
    size = int(rng.integers(1, 4096))
    if kind == "flip":
        for _ in range(int(rng.integers(1, 9))):
            i = int(np.clip(at + rng.integers(-32, 32), 0, n - 1))
            out[i] ^= 1 << int(rng.integers(8))
    elif kind == "garbage":
        out[at : at + size] = rng.bytes(len(out[at : at + size]))
    elif kind == "cut":
        del out[at:]
    elif kind == "insert":
        out[at:at] = rng.bytes(size)
    elif kind == "delete":
        del out[at : at + size]
    elif kind == "repeat":
        out[at:at] = out[at : at + size]
    else:
        out[at : at + size] = bytes(len(out[at : at + size]))
    return bytes(out), f"{kind} at {at} ({size} bytes)"


@pytest.mark.parametrize("fmt", ["bag", "mcap"])
def test_mutated_bag_files(tmp_path, capsys, fmt):
    source = sample_sequence(fmt, 4)
    data = source.read_bytes()
    anchors = _anchors(data)
    rng = np.random.default_rng(1900 + len(fmt))
    outcomes = {"read": 0, "error": 0}
    path = tmp_path / f"fuzz.{fmt}"
    for k in range(BAG_MUTATIONS):
        blob, what = mutate(data, rng, anchors)
        path.write_bytes(blob)
        outcomes[check_input(path, capsys, f"{fmt} #{k}: {what}")] += 1
    # Most single mutations leave most of the bag readable.
    assert outcomes["read"] > BAG_MUTATIONS // 2, outcomes


def _mutated_message(msg, rng: np.random.Generator):
    """A PointCloud2 message with one seeded mutation of its layout, fields or data."""
    kind = rng.integers(8)
    big = [0, 1, 2, 3, 7, 21, 22, 23, 2**16, 2**31 - 1, 2**32 - 1]
    pick = lambda: int(big[rng.integers(len(big))])  # noqa: E731
    if kind == 0:
        return dataclasses.replace(msg, width=pick())
    if kind == 1:
        return dataclasses.replace(msg, height=pick())
    if kind == 2:
        return dataclasses.replace(msg, point_step=pick())
    if kind == 3:
        return dataclasses.replace(msg, row_step=pick())
    if kind == 4:
        return dataclasses.replace(msg, is_bigendian=not msg.is_bigendian)
    if kind == 5:
        data = msg.data[: int(rng.integers(len(msg.data) + 1))]
        return dataclasses.replace(msg, data=data)
    fields = list(msg.fields)
    i = int(rng.integers(len(fields)))
    if kind == 6:
        change = ["offset", "datatype", "count"][rng.integers(3)]
        value = pick() if change != "datatype" else int(rng.integers(0, 12))
        fields[i] = dataclasses.replace(fields[i], **{change: value})
    else:
        names = ["x", "y", "z", "", "time", "ring", "t", "intensity"]
        fields[i] = dataclasses.replace(fields[i], name=names[rng.integers(len(names))])
        if rng.random() < 0.3:
            del fields[int(rng.integers(len(fields)))]
    return dataclasses.replace(msg, fields=fields)


def test_mutated_pointcloud2_fields(tmp_path, capsys):
    from rosbags.rosbag1 import Writer

    from forestslam.io.bags import POINTCLOUD2, _message, _typestore

    store = _typestore(True)
    scans = [s.select(np.arange(0, len(s), 10)) for s in read_scans(sample_sequence("bag", 4))]
    rng = np.random.default_rng(1901)
    for b in range(FIELD_BAGS):
        path = tmp_path / f"fields{b}.bag"
        with Writer(path) as writer:
            conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
            for k in range(MESSAGES_PER_BAG):
                ns, msg = _message(store, True, scans[k % len(scans)], k, "velodyne")
                msg = _mutated_message(msg, rng) if k % 5 else msg  # some stay sound
                writer.write(conn, ns + k, store.serialize_ros1(msg, POINTCLOUD2))
        assert check_input(path, capsys, f"field bag {b}") == "read"
        stream = read_scans(path)
        assert len(list(stream)) >= 2  # the sound messages
        assert stream.stats.messages == MESSAGES_PER_BAG


def test_a_few_in_a_new_process(tmp_path):
    """The console entry, where a crash (signal) or a traceback would show."""
    data = sample_sequence("bag", 4).read_bytes()
    rng = np.random.default_rng(1902)
    anchors = _anchors(data)
    root = Path(__file__).resolve().parents[1]
    for k in range(3):
        blob, what = mutate(data, rng, anchors)
        path = tmp_path / f"p{k}.bag"
        path.write_bytes(blob)
        result = subprocess.run(
            [sys.executable, "-m", "forestslam.cli.main", "info", str(path)],
            capture_output=True,
            text=True,
            timeout=HANG_S * 2,
            env={"PYTHONPATH": f"{root / 'python'}:{':'.join(sys.path)}", "PATH": "/usr/bin"},
        )
        assert result.returncode in (0, 1), (what, result.stderr)
        assert "Traceback" not in result.stderr, (what, result.stderr)
