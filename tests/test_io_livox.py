"""Livox CustomMsg scans read from ROS1 and ROS2 bags without ROS, by their stored definition."""

from __future__ import annotations

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import read_scans

POINT = (
    "uint32 offset_time\nfloat32 x\nfloat32 y\nfloat32 z\nuint8 reflectivity\nuint8 tag\n"
    "uint8 line\n"
)
CUSTOM = (
    "std_msgs/Header header\nuint64 timebase\nuint32 point_num\nuint8 lidar_id\nuint8[3] rsvd\n"
    "livox_ros_driver2/CustomPoint[] points\n"
)
MSGTYPE = "livox_ros_driver2/msg/CustomMsg"


def _write(path, scans, point_def=POINT):
    """A bag of CustomMsg, each scan (timebase ns, (N,3) xyz, (N,) line, (N,) offset ns),
    written with a type store of its own (the reader must use the bag's stored definition)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros1 = path.suffix == ".bag"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(point_def, "livox_ros_driver2/msg/CustomPoint"))
    store.register(get_types_from_msg(CUSTOM, MSGTYPE))
    T = store.types
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, serialize, target = Writer(path), store.serialize_ros1, path
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path.with_suffix(""), version=8, storage_plugin=StoragePlugin.MCAP)
        serialize, target = store.serialize_cdr, path.with_suffix("") / f"{path.stem}.mcap"
    with writer:
        conn = writer.add_connection("/livox/lidar", MSGTYPE, typestore=store)
        for seq, (timebase, xyz, line, offset) in enumerate(scans):
            stamp = T["builtin_interfaces/msg/Time"](
                sec=timebase // 10**9, nanosec=timebase % 10**9
            )
            header = T["std_msgs/msg/Header"](
                **({"seq": seq} if ros1 else {}), stamp=stamp, frame_id="livox_frame"
            )
            fields = {"tag": 0, **({"extra": 0.0} if "extra" in point_def else {})}
            points = [
                T["livox_ros_driver2/msg/CustomPoint"](
                    **(
                        fields
                        | {
                            "offset_time": int(o),
                            "x": float(p[0]),
                            "y": float(p[1]),
                            "z": float(p[2]),
                            "reflectivity": int(k) % 256,
                            "line": int(r),
                        }
                    )
                )
                for k, (p, r, o) in enumerate(zip(xyz, line, offset, strict=True))
            ]
            msg = T[MSGTYPE](
                header=header,
                timebase=timebase,
                point_num=len(points),
                lidar_id=0,
                rsvd=np.zeros(3, np.uint8),
                points=points,
            )
            writer.write(conn, timebase, serialize(msg, MSGTYPE))
    return target


def _scans(n=2, points=500, seed=0):
    rng = np.random.default_rng(seed)
    return [
        (
            1_700_000_000_000_000_000 + k * 100_000_000,
            rng.uniform(-20, 20, (points, 3)).astype(np.float32),
            rng.integers(0, 4, points),
            np.sort(rng.integers(0, 100_000_000, points)),
        )
        for k in range(n)
    ]


@pytest.mark.parametrize("suffix", [".bag", ".mcap"])
def test_custom_msg_points_ring_time_and_stamp(tmp_path, suffix):
    truth = _scans()
    stream = read_scans(_write(tmp_path / f"livox{suffix}", truth))
    scans = list(stream)
    assert len(scans) == 2 and stream.source.msgtype == MSGTYPE
    for scan, (timebase, xyz, line, offset) in zip(scans, truth, strict=True):
        assert scan.stamp == pytest.approx(timebase * 1e-9, abs=1e-6)
        np.testing.assert_array_equal(scan.points, xyz.astype(np.float64))
        np.testing.assert_array_equal(scan.ring, line)
        np.testing.assert_allclose(scan.time, offset * 1e-9, atol=1e-12)
        np.testing.assert_array_equal(scan.intensity, np.arange(len(xyz)) % 256)


def test_custom_msg_of_another_layout_is_refused(tmp_path):
    other = POINT.replace("uint8 line\n", "uint8 line\nfloat32 extra\n")
    path = _write(tmp_path / "odd.bag", _scans(n=1, points=5), point_def=other)
    with pytest.raises(InputError, match="another layout"):
        read_scans(path)
