"""Raw Velodyne packets (pcap captures, packet streams) decode to the returns they hold."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from velodyne_packets import (
    BLOCK_US,
    DUAL,
    VLP16_ELEVATION_DEG,
    VLP16_VERTICAL_MM,
    expected_points,
    udp_frame,
    vlp16_packet,
    write_velodyne_bag,
)

from forestslam.errors import InputError
from forestslam.io import open_source, read_scans
from forestslam.io.velodyne import PacketConfig, PacketStream

STEP_CDEG = 40  # 0.4 deg per block: a VLP-16 at 10 Hz
PACKETS_PER_REV = 75
T0 = 1_700_000_000.0
RING_OF_LASER = np.argsort(np.argsort(VLP16_ELEVATION_DEG))


def _packets(n, seed=1):
    """n consecutive packets from azimuth 0: (host stamp, payload, expected points/ring/time)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        az = (np.arange(12) + 12 * k) * STEP_CDEG
        ranges = rng.integers(1000, 3000, size=(12, 32))  # 2-6 m in 2 mm units
        inten = rng.integers(1, 255, size=(12, 32))
        device_us = k * 12 * BLOCK_US
        packet = vlp16_packet(az, ranges, inten, device_us)
        pts, ring, t = expected_points(az % 36000, ranges, STEP_CDEG)
        out.append((T0 + device_us * 1e-6, packet, pts, ring, t + device_us * 1e-6))
    return out


def _first_scan(packets, config=PacketConfig()):
    stream = PacketStream(config)
    for stamp, payload, *_ in packets:
        scan = stream.push(stamp, payload)
        if scan is not None:
            return scan
    return stream.finish()


def _write_pcap(path, packets, cut_last=0):
    import dpkt

    with open(path, "wb") as f:
        writer = dpkt.pcap.Writer(f)
        for stamp, payload, *_ in packets:
            writer.writepkt(udp_frame(payload), ts=stamp)
    if cut_last:
        with open(path, "r+b") as f:
            f.truncate(path.stat().st_size - cut_last)


def test_packets_decode_to_their_points_ring_and_time():
    packets = _packets(PACKETS_PER_REV + 5)
    scan = _first_scan(packets)
    pts = np.vstack([p[2] for p in packets])
    rings = np.concatenate([p[3] for p in packets])
    times = np.concatenate([p[4] for p in packets])
    dist, idx = cKDTree(pts).query(scan.points)
    assert len(scan) >= 0.95 * PACKETS_PER_REV * 384
    assert dist.max() < 1e-3  # within 1 mm
    assert np.array_equal(scan.ring, rings[idx])
    assert scan.stamp == pytest.approx(T0, abs=1e-6)
    np.testing.assert_allclose(scan.time, times[idx], atol=2e-6)
    assert scan.intensity is not None and scan.intensity.max() < 255


def test_dual_return_packets_give_both_returns():
    """Dual-return packets: block pairs share an azimuth, the first holding the last return
    (here 0.2 m behind) and the second the strongest; both are decoded, each on its ring."""
    rng = np.random.default_rng(3)
    packets, expected = [], {r: [] for r in range(16)}
    for k in range(PACKETS_PER_REV * 2 + 5):
        az = np.repeat(np.arange(6) + 6 * k, 2) * STEP_CDEG  # a pair spans one block's time
        strongest = rng.integers(1000, 3000, size=(6, 32))
        ranges = np.empty((12, 32), dtype=np.int64)
        ranges[0::2], ranges[1::2] = strongest + 100, strongest
        device_us = k * 6 * BLOCK_US
        packets.append(
            (T0 + device_us * 1e-6, vlp16_packet(az, ranges, ranges % 200 + 1, device_us, DUAL))
        )
        for c in range(32):
            expected[RING_OF_LASER[c % 16]].extend(ranges[:, c] * 0.002)
    scan = _first_scan(packets)
    assert len(scan) >= 0.95 * PACKETS_PER_REV * 2 * 384  # both returns of every firing
    vertical = VLP16_VERTICAL_MM[np.argsort(VLP16_ELEVATION_DEG)] * 1e-3  # by ring
    for ring in range(16):
        pts = scan.points[scan.ring == ring]
        ranges = np.linalg.norm(pts - [0.0, 0.0, vertical[ring]], axis=1)
        gap = np.abs(ranges[:, None] - np.unique(expected[ring])[None, :]).min(axis=1)
        assert gap.max() < 1e-3


def test_pcap_reads_revolutions_and_counts_them(tmp_path):
    path = tmp_path / "capture.pcap"
    _write_pcap(path, _packets(3 * PACKETS_PER_REV + 10))
    source = open_source(path)
    assert source.format == "pcap"
    scans = list(read_scans(path))
    assert len(source) == len(scans) == 4  # three whole revolutions and the start of a fourth
    assert np.all(np.diff([s.stamp for s in scans]) > 0.09)
    assert set(source.fields()) >= {"x", "y", "z", "intensity", "ring", "time"}


def test_pcap_cut_mid_packet_is_read_up_to_the_damage(tmp_path):
    path = tmp_path / "cut.pcap"
    packets = _packets(2 * PACKETS_PER_REV + 3)
    _write_pcap(path, packets, cut_last=500)
    stream = read_scans(path)
    scans = list(stream)
    assert len(scans) == 3
    assert stream.stats.lost_bytes > 0
    assert any("cut" in w for w in stream.stats.warnings)


def test_file_that_is_not_a_capture_is_a_clear_error(tmp_path):
    path = tmp_path / "junk.pcap"
    path.write_bytes(b"not a capture at all" * 10)
    with pytest.raises(InputError, match="pcap"):
        open_source(path)


def test_unknown_packet_model_is_a_clear_error():
    with pytest.raises(InputError, match="VLP16"):
        PacketStream(PacketConfig(model="VLP99"))


@pytest.mark.parametrize("suffix", [".bag", ".mcap"])
def test_velodyne_scan_messages_in_ros1_and_ros2_bags(tmp_path, suffix):
    packets = _packets(2 * PACKETS_PER_REV, seed=4)
    revolutions = [
        [(p[0], p[1]) for p in packets[:PACKETS_PER_REV]],
        [(p[0], p[1]) for p in packets[PACKETS_PER_REV:]],
    ]
    path = write_velodyne_bag(tmp_path / f"packets{suffix}", revolutions)
    stream = read_scans(path)
    assert stream.source.topics()[0].msgtype == "velodyne_msgs/msg/VelodyneScan"
    scans = list(stream)
    assert len(scans) == len(stream) == 2
    pts = np.vstack([p[2] for p in packets[:PACKETS_PER_REV]])
    rings = np.concatenate([p[3] for p in packets[:PACKETS_PER_REV]])
    dist, idx = cKDTree(pts).query(scans[0].points)
    assert len(scans[0]) == len(pts)
    assert dist.max() < 1e-3
    assert np.array_equal(scans[0].ring, rings[idx])
    assert scans[1].stamp == pytest.approx(packets[PACKETS_PER_REV][0], abs=1e-6)


def test_profile_of_another_model_is_refused(tmp_path):
    from forestslam.sensors import load_profile

    path = tmp_path / "vlp16.pcap"
    _write_pcap(path, _packets(PACKETS_PER_REV + 2))
    assert len(list(read_scans(path, packets=load_profile("vlp16").packet_config()))) == 2
    with pytest.raises(InputError, match="VLP16.*HDL32E"):
        list(read_scans(path, packets=load_profile("hdl32").packet_config()))
