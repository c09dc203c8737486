"""ROS bags: write_scans/read_scans round trips, topic choice, damaged and corrupt bags."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from forestslam.errors import InputError
from forestslam.io import Scan, open_source, read_scans, write_scans
from forestslam.io.bags import POINTCLOUD2, _message, _typestore


def make_scans(count: int, n: int = 500, seed: int = 0) -> list[Scan]:
    rng = np.random.default_rng(seed)
    scans = []
    for k in range(count):
        m = n + k  # different sizes per scan
        scans.append(
            Scan(
                1_600_000_000.0 + 0.1 * k + 1e-6 * k,
                rng.uniform(-30, 30, (m, 3)),
                rng.uniform(0, 255, m).astype(np.float32),
                rng.integers(0, 16, m).astype(np.uint16),
                np.sort(rng.uniform(0, 0.1, m)),
            )
        )
    return scans


def assert_same(a: Scan, b: Scan) -> None:
    assert b.stamp == pytest.approx(a.stamp, abs=1e-6)  # float64 at 1.6e9 s
    np.testing.assert_array_equal(b.points, a.points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(b.intensity, a.intensity)
    np.testing.assert_array_equal(b.ring, a.ring)
    np.testing.assert_array_equal(b.time, a.time.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize("suffix", [".bag", ".mcap", ".db3"])
def test_round_trip(tmp_path, suffix):
    scans = make_scans(12)
    path = tmp_path / f"seq{suffix}"
    assert write_scans(path, iter(scans)) == 12  # a generator is fine
    assert path.is_file() and [p.name for p in tmp_path.iterdir()] == [path.name]
    stream = read_scans(path)
    assert len(stream) == 12
    out = list(stream)
    assert len(out) == 12
    for a, b in zip(scans, out, strict=True):
        assert_same(a, b)
    assert stream.stats.scans == 12 and stream.stats.skipped == 0
    source = open_source(path)
    assert source.format in ("ros1", "ros2-mcap", "ros2-db3")
    assert [(t.name, t.msgtype, t.count) for t in source.topics()] == [
        ("/velodyne_points", POINTCLOUD2, 12)
    ]
    assert source.fields() == {
        "x": "float32",
        "y": "float32",
        "z": "float32",
        "intensity": "float32",
        "ring": "uint16",
        "time": "float32",
    }


def test_overwrite_missing_fields_and_empty_scan(tmp_path):
    path = tmp_path / "a.bag"
    write_scans(path, make_scans(2))
    scans = [Scan(5.0, np.ones((12, 3))), Scan(5.1, np.zeros((0, 3)))]
    write_scans(path, scans, topic="/points", frame_id="lidar")  # replaces the old bag
    stream = read_scans(path, topic="/points")
    out = list(stream)
    assert len(out) == 1  # the empty scan is skipped and counted
    assert stream.stats.degraded == {"empty_scans": 1, "ring_ignored": 1}
    np.testing.assert_array_equal(out[0].points, np.ones((12, 3)))
    assert out[0].ring is None  # written as 0 in the layout: no ring information


def test_bad_suffix(tmp_path):
    with pytest.raises(InputError, match="suffix"):
        write_scans(tmp_path / "a.txt", make_scans(1))


def write_topics(path, topics: dict[str, list[Scan]]):
    from rosbags.rosbag1 import Writer

    store = _typestore(True)
    with Writer(path) as writer:
        for topic, scans in topics.items():
            conn = writer.add_connection(topic, POINTCLOUD2, typestore=store)
            for k, scan in enumerate(scans):
                ns, msg = _message(store, True, scan, k, "x")
                writer.write(conn, ns, store.serialize_ros1(msg, POINTCLOUD2))
        std = get_typestore(Stores.ROS1_NOETIC)  # a topic of another type
        imu = writer.add_connection("/imu", "std_msgs/msg/String", typestore=std)
        writer.write(
            imu,
            1,
            std.serialize_ros1(std.types["std_msgs/msg/String"]("hi"), "std_msgs/msg/String"),
        )


@pytest.mark.parametrize("ros1", [True, False])
def test_scan_types_match_the_standard_store(ros1):
    """The reader's small type store defines the scan messages exactly as rosbags' standard
    store of that ROS version (fields, constants and, for ROS1 bags, the md5 written)."""
    full = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store = _typestore(ros1)
    for name in (POINTCLOUD2, "sensor_msgs/msg/PointField", "std_msgs/msg/Header"):
        assert store.fielddefs[name] == full.fielddefs[name], name
        version = 1 if ros1 else 2
        assert store.generate_msgdef(name, ros_version=version) == full.generate_msgdef(
            name, ros_version=version
        ), name


def test_topic_choice(tmp_path):
    path = tmp_path / "two.bag"
    write_topics(path, {"/front": make_scans(3), "/rear": make_scans(2, seed=1)})
    with pytest.raises(InputError) as err:
        read_scans(path)
    text = str(err.value)
    assert "several PointCloud2 topics" in text and "/front (3 msgs)" in text
    assert "/rear (2 msgs)" in text and str(path) in text
    assert len(list(read_scans(path, topic="/rear"))) == 2
    with pytest.raises(InputError, match=r"no topic '/top'.*/front.*3 msgs.*/imu"):
        read_scans(path, topic="/top")
    with pytest.raises(InputError, match="not PointCloud2"):
        read_scans(path, topic="/imu")


def test_time_order_across_interleaved_writes(tmp_path):
    scans = make_scans(6)
    path = tmp_path / "shuffled.bag"
    write_scans(path, [scans[i] for i in (3, 0, 5, 1, 4, 2)])
    stamps = [s.stamp for s in read_scans(path)]
    assert stamps == sorted(stamps) and len(stamps) == 6


def _kill_recorder(data: bytes, keep: float) -> bytes:
    """What a killed recorder leaves: index_pos 0 in the bag header, the file cut short."""
    out = bytearray(data[: int(len(data) * keep)])
    i = out.index(b"index_pos=") + len(b"index_pos=")
    out[i : i + 8] = bytes(8)
    return bytes(out)


@pytest.mark.parametrize("compression", [None, "lz4", "bz2"])
def test_truncated_bag_reads_intact_chunks(tmp_path, compression, caplog):
    from rosbags.rosbag1 import Writer

    scans = make_scans(40, n=1000)  # 22 kB each: about 5 per 100 kB chunk
    full = tmp_path / "full.bag"
    store = _typestore(True)
    writer = Writer(full)
    writer.chunk_threshold = 100_000
    if compression:
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    with writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, True, scan, k, "velodyne")
            writer.write(conn, ns, store.serialize_ros1(msg, POINTCLOUD2))
    data = full.read_bytes()
    for name, blob in (
        ("killed.bag", _kill_recorder(data, 0.6)),
        ("cut.bag", data[: int(len(data) * 0.6)]),  # index_pos points past the end
    ):
        path = tmp_path / name
        path.write_bytes(blob)
        stream = read_scans(path)
        out = list(stream)
        # Everything read is exact and in order; most of what fits in 60 % is recovered.
        assert 12 <= len(out) <= 24
        for a, b in zip(scans, out, strict=False):
            assert_same(a, b)
        assert stream.stats.lost_bytes > 0
        assert any("lost" in w for w in stream.stats.warnings)
    assert "lost" in caplog.text


def test_truncated_before_first_chunk(tmp_path):
    path = tmp_path / "a.bag"
    write_scans(path, make_scans(3))
    path.write_bytes(_kill_recorder(path.read_bytes(), 1.0)[:3000])
    with pytest.raises(InputError, match=str(path)):
        read_scans(path)


def test_corrupt_message_mid_bag_is_skipped_and_counted(tmp_path, caplog):
    from rosbags.rosbag1 import Writer

    scans = make_scans(5)
    store = _typestore(True)
    path = tmp_path / "corrupt.bag"
    with Writer(path) as writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, True, scan, k, "velodyne")
            raw = bytes(store.serialize_ros1(msg, POINTCLOUD2))
            if k == 2:
                raw = raw[:200]  # cut inside the point data
            writer.write(conn, ns, raw)
    stream = read_scans(path)
    out = list(stream)
    assert [s.stamp for s in out] == pytest.approx([scans[i].stamp for i in (0, 1, 3, 4)])
    assert stream.stats.skipped == 1 and stream.stats.messages == 5
    assert "corrupt message skipped" in caplog.text


@pytest.mark.parametrize("content", [b"", b"not a bag at all\n" * 50])
def test_garbage_bag(tmp_path, content):
    path = tmp_path / "bad.bag"
    path.write_bytes(content)
    with pytest.raises(InputError, match="bad.bag"):
        read_scans(path)
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(InputError, match="bad.mcap"):
        read_scans(path)


def test_missing_and_unsupported(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_scans(tmp_path / "nope.bag")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="unsupported input type '.txt'"):
        read_scans(tmp_path / "notes.txt")


@pytest.mark.parametrize("compression", [None, "lz4"])
def test_damaged_chunk_mid_bag_is_skipped_and_the_rest_read(tmp_path, compression, caplog):
    from rosbags.rosbag1 import Writer

    from forestslam.io.ros1_salvage import build_index

    scans = make_scans(30, n=1000)
    path = tmp_path / "damaged.bag"
    store = _typestore(True)
    writer = Writer(path)
    writer.chunk_threshold = 100_000
    if compression:
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    with writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, True, scan, k, "velodyne")
            writer.write(conn, ns, store.serialize_ros1(msg, POINTCLOUD2))
    index = build_index(path)
    assert len(index.chunks) >= 4 and not index.bad_chunks
    victim = index.chunks[2]
    lost = {e[0] for e in index.entries if e[2] == 2}
    data = bytearray(path.read_bytes())
    # Break the lz4 frame magic, or the first record header inside an uncompressed chunk.
    data[victim.datapos : victim.datapos + 4] = b"\xff\xff\xff\x7f"
    path.write_bytes(bytes(data))

    stream = read_scans(path)
    out = list(stream)
    expected = [s for s in scans if round(s.stamp * 1e9) not in lost]
    assert len(lost) >= 2 and len(out) == len(expected) == 30 - len(lost)
    for a, b in zip(expected, out, strict=True):
        assert_same(a, b)
    assert stream.stats.skipped == len(lost) and stream.stats.damaged_chunks == 1
    assert "damaged chunk" in caplog.text


def test_killed_recorder_with_unfinished_chunk_header(tmp_path):
    """rosbag (C++) writes a chunk header with data length 0 and rewrites it when the chunk
    closes; a recorder killed mid-chunk leaves the 0 and message records running to the end."""
    from rosbags.rosbag1 import Writer

    from forestslam.io.ros1_salvage import build_index

    scans = make_scans(20, n=1000)
    path = tmp_path / "rec.bag"
    store = _typestore(True)
    writer = Writer(path)
    writer.chunk_threshold = 100_000
    with writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, True, scan, k, "velodyne")
            writer.write(conn, ns, store.serialize_ros1(msg, POINTCLOUD2))
    index = build_index(path)
    last = index.chunks[-2]  # cut inside the second-to-last chunk
    in_last = sorted(e[3] + e[4] for e in index.entries if e[2] == len(index.chunks) - 2)
    cut = last.datapos + (in_last[0] + in_last[1]) // 2  # after its first message, mid second
    data = bytearray(_kill_recorder(path.read_bytes(), 1.0)[:cut])
    data[last.datapos - 4 : last.datapos] = bytes(4)  # chunk data length never rewritten
    damaged = tmp_path / "killed.bag"
    damaged.write_bytes(bytes(data))
    before = sum(1 for e in index.entries if e[2] < len(index.chunks) - 2)
    stream = read_scans(damaged)
    out = list(stream)
    assert len(out) == before + 1  # every earlier chunk plus the complete first message
    for a, b in zip(scans, out, strict=False):
        assert_same(a, b)
    assert 0 < stream.stats.lost_bytes < in_last[1] - in_last[0]


@pytest.mark.parametrize("plugin", ["SQLITE3", "MCAP"])
def test_ros2_bag_directory(tmp_path, plugin):
    from rosbags.rosbag2 import StoragePlugin, Writer

    scans = make_scans(4)
    store = _typestore(False)
    bagdir = tmp_path / "rosbag2_dir"
    with Writer(bagdir, version=8, storage_plugin=StoragePlugin[plugin]) as writer:
        conn = writer.add_connection("/ouster/points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, False, scan, k, "os_sensor")
            writer.write(conn, ns, store.serialize_cdr(msg, POINTCLOUD2))
    source = open_source(bagdir)
    assert source.format == "ros2-dir" and source.topic == "/ouster/points"
    out = list(source.scans())
    assert len(out) == 4
    for a, b in zip(scans, out, strict=True):
        assert_same(a, b)


def test_failed_write_leaves_no_file(tmp_path):
    def scans_then_crash():
        yield from make_scans(2)
        raise RuntimeError("simulator crashed")

    path = tmp_path / "seq.bag"
    write_scans(path, make_scans(3))  # a previous complete bag stays intact
    with pytest.raises(RuntimeError, match="crashed"):
        write_scans(path, scans_then_crash())
    assert [p.name for p in tmp_path.iterdir()] == ["seq.bag"]
    assert len(list(read_scans(path))) == 3


def test_start_skips_without_decoding(tmp_path):
    scans = make_scans(6)
    path = tmp_path / "a.mcap"
    write_scans(path, scans)
    stream = read_scans(path, start=4)
    out = list(stream)
    assert len(stream) == 6 and stream.stats.messages == 2
    assert [s.stamp for s in out] == pytest.approx([scans[4].stamp, scans[5].stamp])
    with pytest.raises(InputError, match="start"):
        read_scans(path, start=-1)


def test_truncated_mcap_reads_intact_chunks(tmp_path, caplog):
    """`ros2 bag record` killed: the MCAP has no summary or footer and ends mid-chunk."""
    scans = make_scans(30, n=3000)  # 66 kB each, 1 MB chunks
    full = tmp_path / "full.mcap"
    write_scans(full, scans)
    data = full.read_bytes()
    for keep in (0.3, 0.6, 0.97):
        path = tmp_path / f"cut{keep}.mcap"
        path.write_bytes(data[: int(len(data) * keep)])
        stream = read_scans(path)
        out = list(stream)
        assert int(30 * keep) - 2 <= len(out) <= int(30 * keep)
        for a, b in zip(scans, out, strict=False):
            assert_same(a, b)
        assert stream.stats.lost_bytes > 0
    assert "MCAP summary unusable" in caplog.text
    path = tmp_path / "head.mcap"
    path.write_bytes(data[:40])
    with pytest.raises(InputError, match="head.mcap"):
        read_scans(path)


def test_mcap_damaged_chunk_mid_file(tmp_path):
    from forestslam.io.mcap_salvage import build_index

    scans = make_scans(40, n=3000)
    path = tmp_path / "d.mcap"
    write_scans(path, scans)
    index = build_index(path)
    assert len(index.chunks) >= 3 and not index.damaged
    lost = {e[0] for e in index.entries if e[2] == 1}
    first_message = min(e[3] for e in index.entries if e[2] == 1)
    data = bytearray(path.read_bytes())
    start = index.chunks[1].datapos + first_message - 22 - 9  # the record's opcode and length
    data[start + 1 : start + 9] = (2**60).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    stream = read_scans(path)
    out = list(stream)
    expected = [s for s in scans if round(s.stamp * 1e9) not in lost]
    assert len(lost) >= 10 and len(out) == len(expected)
    for a, b in zip(expected, out, strict=True):
        assert_same(a, b)
    assert stream.stats.skipped == len(lost) and stream.stats.damaged_chunks == 1


def test_truncated_zstd_mcap(tmp_path):
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    scans = make_scans(30, n=3000)
    store = _typestore(False)
    bagdir = tmp_path / "z"
    writer = Writer(bagdir, version=8, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k, scan in enumerate(scans):
            ns, msg = _message(store, False, scan, k, "velodyne")
            writer.write(conn, ns, store.serialize_cdr(msg, POINTCLOUD2))
    data = (bagdir / "z.mcap").read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: int(len(data) * 0.7)])
    out = list(read_scans(path))
    assert 10 <= len(out) <= 21  # complete chunks plus the decodable part of the cut one
    for a, b in zip(scans, out, strict=False):
        assert_same(a, b)
