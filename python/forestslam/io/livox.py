"""Livox `CustomMsg` scans (livox_ros_driver2, and livox_ros_driver of the same layout) without ROS.

The message definition is the one the recorder stored in the bag (ROS1 connection header, MCAP
schema): forestslam checks it against the driver's CustomMsg/CustomPoint layout and then reads
the point array with numpy straight from the serialized bytes, since rosbags would build one
Python object per point. Fields: x y z (float32, m), reflectivity -> intensity, line -> ring,
offset_time (ns after `timebase`) -> per-point time; the scan's stamp is `timebase`.
"""

from __future__ import annotations

import re

import numpy as np

from forestslam.io.scan import Scan

CUSTOM_MSG_TYPES = ("livox_ros_driver2/msg/CustomMsg", "livox_ros_driver/msg/CustomMsg")
_CUSTOM_FIELDS = [
    ("std_msgs/Header", "header"),
    ("uint64", "timebase"),
    ("uint32", "point_num"),
    ("uint8", "lidar_id"),
    ("uint8[3]", "rsvd"),
    ("CustomPoint[]", "points"),
]
_POINT_FIELDS = [
    ("uint32", "offset_time"),
    ("float32", "x"),
    ("float32", "y"),
    ("float32", "z"),
    ("uint8", "reflectivity"),
    ("uint8", "tag"),
    ("uint8", "line"),
]
_POINT = [("offset_time", "<u4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
_POINT += [("reflectivity", "u1"), ("tag", "u1"), ("line", "u1")]


def _fields(text: str) -> list[tuple[str, str]]:
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line and "=" not in line:
            kind, name = line.split()[:2]
            out.append((kind.rsplit("/", 1)[-1] if kind.endswith("[]") else kind, name))
    return out


def layout_matches(msgdef: str) -> bool:
    """Whether a stored definition (ROS1 text with `MSG:` sections, or ros2msg) is the driver's
    CustomMsg with CustomPoint, field for field."""
    sections = re.split(r"\n=+\nMSG: ", msgdef)
    main = _fields(sections[0])
    header = main[0][0] in ("std_msgs/Header", "Header") and main[0][1] == "header"
    points = [
        _fields(s.split("\n", 1)[1])
        for s in sections[1:]
        if s.split("\n", 1)[0].endswith("CustomPoint")
    ]
    point_ok = not points or points[0] == _POINT_FIELDS
    return (
        header
        and main[1:] == _CUSTOM_FIELDS[1:]
        and point_ok
        and (len(sections) == 1 or bool(points))
    )


def decode_custom_msg(raw: bytes, cdr: bool) -> Scan:
    """A Scan from one serialized CustomMsg (ROS1 or ROS2 CDR little endian)."""
    buf = memoryview(raw)
    if cdr:
        pos = 4 + 8  # encapsulation header, stamp (sec, nanosec)
        pos += 4 + int.from_bytes(buf[pos : pos + 4], "little")  # frame_id with its NUL
        align = lambda p, n: 4 + (p - 4 + n - 1) // n * n  # noqa: E731 - CDR offsets after the header
    else:
        pos = 4 + 8  # seq, stamp
        pos += 4 + int.from_bytes(buf[pos : pos + 4], "little")  # frame_id
        align = lambda p, n: p  # noqa: E731 - ROS1 is packed
    pos = align(pos, 8)
    timebase = int.from_bytes(buf[pos : pos + 8], "little")
    pos = align(pos + 8 + 4 + 1 + 3, 4)  # point_num, lidar_id, rsvd[3]
    count = int.from_bytes(buf[pos : pos + 4], "little")
    pos += 4
    stride = 20 if cdr else 19  # CDR pads each point to its u32 alignment
    dtype = np.dtype(
        {
            "names": [n for n, _ in _POINT],
            "formats": [f for _, f in _POINT],
            "offsets": [0, 4, 8, 12, 16, 17, 18],
            "itemsize": stride,
        }
    )
    need = pos + (count - 1) * stride + 19 if count else pos
    if need > len(buf):
        raise ValueError(f"CustomMsg announces {count} points but holds {len(buf) - pos} bytes")
    pts = np.zeros(count, dtype=dtype)
    if count:
        whole = bytes(buf[pos : pos + count * stride].tobytes().ljust(count * stride, b"\0"))
        pts = np.frombuffer(whole, dtype=dtype, count=count)
    xyz = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float64)
    keep = np.isfinite(xyz).all(axis=1) & np.any(xyz != 0.0, axis=1)
    return Scan(
        timebase * 1e-9,
        xyz[keep],
        intensity=pts["reflectivity"][keep].astype(np.float32),
        ring=pts["line"][keep].astype(np.uint16),
        time=pts["offset_time"][keep].astype(np.float64) * 1e-9,
    )
