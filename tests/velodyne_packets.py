"""Velodyne VLP-16 packets built from known returns, by the datasheet (independent of any
decoder): 12 blocks of 2 firing sequences x 16 lasers, 2 mm range units, 0.01 deg azimuths."""

from __future__ import annotations

import struct

import numpy as np

# Laser id -> elevation (deg), VLP-16 datasheet order; ring = beams counted from the lowest up.
VLP16_ELEVATION_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15.0])
# Vertical offset of each laser's origin (mm), VLP-16 user manual table "vertical correction".
VLP16_VERTICAL_MM = np.array(
    [11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1, 2.2, -9.7, 0.7, -11.2]
)
FIRING_US = 2.304  # between lasers of one sequence
SEQUENCE_US = 55.296  # between the two sequences of a block
BLOCK_US = 110.592
STRONGEST, LAST, DUAL = 0x37, 0x38, 0x39
VLP16 = 0x22


def vlp16_packet(azimuth_cdeg, ranges_units, intensities, device_us, mode=STRONGEST):
    """One packet: `azimuth_cdeg` (12,) block azimuths, `ranges_units` (12, 32) in 2 mm."""
    body = bytearray()
    for b in range(12):
        body += struct.pack("<HH", 0xEEFF, int(azimuth_cdeg[b]) % 36000)
        for c in range(32):
            body += struct.pack("<HB", int(ranges_units[b, c]), int(intensities[b, c]))
    body += struct.pack("<IBB", int(device_us), mode, VLP16)
    return bytes(body)


def expected_points(azimuth_cdeg, ranges_units, step_cdeg):
    """(N,3) points, ring and firing time (s after the packet) of a single-return packet, with
    the datasheet's azimuth interpolation over the block's firing time; ROS frame (x forward,
    y left)."""
    pts, rings, times = [], [], []
    order = np.argsort(VLP16_ELEVATION_DEG)
    ring_of = np.empty(16, dtype=int)
    ring_of[order] = np.arange(16)
    for b in range(12):
        for c in range(32):
            seq, laser = divmod(c, 16)
            t_us = b * BLOCK_US + seq * SEQUENCE_US + laser * FIRING_US
            az = np.radians((azimuth_cdeg[b] + step_cdeg * (t_us - b * BLOCK_US) / BLOCK_US) / 100)
            el = np.radians(VLP16_ELEVATION_DEG[laser])
            r = ranges_units[b, c] * 0.002
            z = r * np.sin(el) + VLP16_VERTICAL_MM[laser] * 1e-3
            pts.append([r * np.cos(el) * np.cos(az), -r * np.cos(el) * np.sin(az), z])
            rings.append(ring_of[laser])
            times.append(t_us * 1e-6)
    return np.array(pts), np.array(rings), np.array(times)


def udp_frame(payload: bytes) -> bytes:
    """An Ethernet/IPv4/UDP frame from the sensor's default address to port 2368."""
    import dpkt

    udp = dpkt.udp.UDP(sport=2368, dport=2368, data=payload)
    udp.ulen = len(udp)
    ip = dpkt.ip.IP(src=bytes([192, 168, 1, 201]), dst=bytes([255, 255, 255, 255]), p=17, data=udp)
    ip.len = len(ip)
    return bytes(dpkt.ethernet.Ethernet(type=dpkt.ethernet.ETH_TYPE_IP, data=ip))


def write_velodyne_bag(path, revolutions, topic="/velodyne_packets"):
    """A ROS1 .bag or ROS2 .mcap with one velodyne_msgs/VelodyneScan per revolution:
    `revolutions` is a list of lists of (host stamp, payload)."""
    from pathlib import Path

    from forestslam.io.bags import VELODYNE_SCAN, _typestore

    path = Path(path)
    ros1 = path.suffix == ".bag"
    store = _typestore(ros1)
    types = store.types
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path.with_suffix(""), version=8, storage_plugin=StoragePlugin.MCAP)
        serialize = store.serialize_cdr

    def stamp(seconds):
        ns = int(round(seconds * 1e9))
        return types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)

    with writer:
        conn = writer.add_connection(topic, VELODYNE_SCAN, typestore=store)
        for seq, packets in enumerate(revolutions):
            t0 = stamp(packets[0][0])
            header = types["std_msgs/msg/Header"](
                **({"seq": seq} if ros1 else {}), stamp=t0, frame_id="velodyne"
            )
            msg = types[VELODYNE_SCAN](
                header=header,
                packets=[
                    types["velodyne_msgs/msg/VelodynePacket"](
                        stamp=stamp(t), data=np.frombuffer(payload, dtype=np.uint8)
                    )
                    for t, payload in packets
                ],
            )
            writer.write(conn, int(round(packets[0][0] * 1e9)), serialize(msg, VELODYNE_SCAN))
    if not ros1:
        return path.with_suffix("") / f"{path.stem}.mcap"
    return path
