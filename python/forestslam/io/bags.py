"""ROS bags without ROS (rosbags): PointCloud2 or raw `velodyne_msgs/VelodyneScan` scans from
ROS1 .bag, ROS2 .db3/.mcap, and a writer for both in the Velodyne driver layout (see
forestslam.io.pointcloud2)."""

from __future__ import annotations

import collections
import functools
import logging
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.checks import check_scan
from forestslam.io.livox import CUSTOM_MSG_TYPES, decode_custom_msg, layout_matches
from forestslam.io.pointcloud2 import (
    VELODYNE_FIELDS,
    VELODYNE_POINT_STEP,
    decode_pointcloud2,
    describe_fields,
    velodyne_array,
)
from forestslam.io.scan import Scan
from forestslam.io.source import ReadStats, TopicInfo
from forestslam.io.velodyne import FIELDS as VELODYNE_FIELDS_DECODED
from forestslam.io.velodyne import VELODYNE_SCAN, PacketConfig, decode_scan_message

log = logging.getLogger(__name__)

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
SCAN_MSGTYPES = (POINTCLOUD2, VELODYNE_SCAN, *CUSTOM_MSG_TYPES)
# velodyne_msgs is not in the standard type stores; its definitions (ROS1 and ROS2 differ only
# in the stamp's type) are registered from the package's .msg files.
_VELODYNE_MSGS = {
    "velodyne_msgs/msg/VelodynePacket": "{time} stamp\nuint8[1206] data",
    VELODYNE_SCAN: "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets",
}
BAG_SUFFIXES = (".bag", ".mcap", ".db3")


# The few standard messages a scan needs (sensor_msgs and std_msgs .msg files): a store of these
# takes ~15 ms to build where the whole ROS1/ROS2 standard store took ~150 ms CPU of every run.
# tests/test_io_bags.py checks them field for field (and the ROS1 md5) against rosbags' stores.
_SCAN_MSGS = {
    "std_msgs/msg/Header": "{seq}{time} stamp\nstring frame_id",
    "sensor_msgs/msg/PointField": "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\n"
    "uint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\n"
    "string name\nuint32 offset\nuint8 datatype\nuint32 count",
    POINTCLOUD2: "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "sensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\n"
    "uint8[] data\nbool is_dense",
}


@functools.lru_cache(maxsize=2)
def _typestore(ros1: bool):
    """rosbags type store of the scan messages (cached), in ROS1 or ROS2 flavour (the Header's
    seq and the stamp's type differ)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)  # builtin_interfaces Time and Duration only
    time = "time" if ros1 else "builtin_interfaces/Time"
    for name, text in (*_SCAN_MSGS.items(), *_VELODYNE_MSGS.items()):
        text = text.format(time=time, seq="uint32 seq\n" if ros1 else "")
        store.register(get_types_from_msg(text, name))
    return store


# --------------------------------------------------------------------------- writing


def _message(store, ros1: bool, scan: Scan, seq: int, frame_id: str):
    types = store.types
    ns = int(round(scan.stamp * 1e9))
    stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    header_type = types["std_msgs/msg/Header"]
    header = (
        header_type(seq=seq, stamp=stamp, frame_id=frame_id)
        if ros1
        else header_type(stamp=stamp, frame_id=frame_id)
    )
    field_type = types["sensor_msgs/msg/PointField"]
    fields = [field_type(name=n, offset=o, datatype=d, count=1) for n, o, d in VELODYNE_FIELDS]
    data = velodyne_array(scan).view(np.uint8).reshape(-1)
    return ns, types[POINTCLOUD2](
        header=header,
        height=1,
        width=len(scan),
        fields=fields,
        is_bigendian=False,
        point_step=VELODYNE_POINT_STEP,
        row_step=VELODYNE_POINT_STEP * len(scan),
        data=data,
        is_dense=True,
    )


def write_scans(
    path: str | Path,
    scans: Iterable[Scan],
    topic: str = "/velodyne_points",
    frame_id: str = "velodyne",
) -> int:
    """Write scans as sensor_msgs/PointCloud2 (Velodyne layout, point_step 22) to a bag.

    The suffix chooses the format: `.bag` ROS1, `.mcap` ROS2 MCAP, `.db3` ROS2 SQLite (the
    storage file alone; rosbags and `ros2 bag` read it). The bag is written beside the target
    and renamed into place at the end, so a crash never leaves a half-written file under
    `path`; an existing file is replaced. `scans` may be a generator. Returns the scan count.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in BAG_SUFFIXES:
        raise InputError(f"{path}: bag suffix must be one of {', '.join(BAG_SUFFIXES)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    ros1 = suffix == ".bag"
    store = _typestore(ros1)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    count = 0
    try:
        if ros1:
            from rosbags.rosbag1 import Writer

            target = tmpdir / path.name
            writer = Writer(target)
            serialize = store.serialize_ros1
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if suffix == ".mcap" else StoragePlugin.SQLITE3
            bagdir = tmpdir / path.stem
            writer = Writer(bagdir, version=8, storage_plugin=plugin)
            target = bagdir / f"{path.stem}{suffix}"
            serialize = store.serialize_cdr
        with writer:
            conn = writer.add_connection(topic, POINTCLOUD2, typestore=store)
            for seq, scan in enumerate(scans):
                ns, msg = _message(store, ros1, scan, seq, frame_id)
                writer.write(conn, ns, serialize(msg, POINTCLOUD2))
                count += 1
        os.replace(target, path)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    log.debug("wrote %d scans to %s", count, path)
    return count


# --------------------------------------------------------------------------- reading


def choose_topic(path: Path, topics: list[TopicInfo], topic: str | None) -> str:
    """The scan topic to read (PointCloud2, VelodyneScan or Livox CustomMsg): `topic` when given,
    else the only one in the bag."""
    listing = ", ".join(f"{t.name} ({t.msgtype}, {t.count} msgs)" for t in topics) or "none"
    clouds = [t for t in topics if t.msgtype in SCAN_MSGTYPES]
    if topic is not None:
        match = [t for t in topics if t.name == topic]
        if not match:
            raise InputError(f"{path}: no topic {topic!r}; topics: {listing}")
        if match[0].msgtype not in SCAN_MSGTYPES:
            raise InputError(
                f"{path}: topic {topic} is {match[0].msgtype}, not PointCloud2, VelodyneScan or "
                "Livox CustomMsg"
            )
        return topic
    if len(clouds) == 1:
        return clouds[0].name
    if not clouds:
        raise InputError(
            f"{path}: no sensor_msgs/PointCloud2, velodyne_msgs/VelodyneScan or Livox CustomMsg "
            "topic; "
            f"topics: {listing}"
        )
    names = ", ".join(f"{t.name} ({t.count} msgs)" for t in clouds)
    kinds = "/".join(sorted({t.msgtype.rsplit("/", 1)[-1] for t in clouds}))
    raise InputError(f"{path}: several {kinds} topics, choose one with --topic: {names}")


class _BagSource:
    """Shared part of the bag readers: topic choice, decoding, skip-and-count."""

    format = "bag"

    def __init__(self, path: Path, topic: str | None, packets: PacketConfig | None = None) -> None:
        self.path = path
        self.stats = ReadStats()
        self._topics = self._read_topics()
        self.topic = choose_topic(path, self._topics, topic)
        self.msgtype = next(t.msgtype for t in self._topics if t.name == self.topic)
        self.packet_config = packets or PacketConfig()  # how VelodyneScan packets are decoded
        if self.msgtype in CUSTOM_MSG_TYPES:
            self._check_livox_layout()

    def topics(self) -> list[TopicInfo]:
        return list(self._topics)

    def __len__(self) -> int:
        return next(t.count for t in self._topics if t.name == self.topic)

    def _open(self):
        """The rosbags reader of this storage (a context manager)."""
        raise NotImplementedError

    def _can_walk(self) -> bool:
        """Whether a salvage walk can resume after a damaged chunk of this storage."""
        return True

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        if self._salvage is not None:
            yield from self._salvaged(self._salvage)
            self.stats.skipped += self._salvage.index.lost_messages(self._ids(self._salvage))
            return
        done: list[int] = []  # stamps already yielded (to resume after a damaged chunk)
        try:
            with self._open() as reader:
                conns = [c for c in reader.connections if c.topic == self.topic]
                for _conn, time_ns, raw in reader.messages(connections=conns):
                    yield time_ns, raw
                    done.append(time_ns)
            return
        except Exception as exc:  # noqa: BLE001 - rosbags/lz4/bz2 raise several types
            failure = exc
        if not self._can_walk():
            self.stats.skipped += max(len(self) - len(done), 0)
            line = f"{self.path}: damaged storage, stopped reading ({_why(failure)})"
            self.stats.warnings.append(line)
            log.warning(line)
            return
        # rosbags stops at a chunk it cannot read: walk the file and resume after that chunk.
        yield from self._resume(self._walk(f"damaged chunk ({_why(failure)})"), done)

    def _read_topics(self) -> list[TopicInfo]:
        raise NotImplementedError

    def _deserialize(self, raw):
        raise NotImplementedError

    def _decode(self, raw, time_ns: int) -> Scan | None:
        where = f"{self.path} {self.topic} message {self.stats.messages}"
        try:
            if self.msgtype == VELODYNE_SCAN:
                return decode_scan_message(self._deserialize(raw), self.packet_config)
            if self.msgtype in CUSTOM_MSG_TYPES:
                return decode_custom_msg(raw, cdr=not isinstance(self, Ros1BagSource))
            return decode_pointcloud2(self._deserialize(raw), where)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is a corrupt message
            self.stats.skipped += 1
            line = f"{where} at t={time_ns * 1e-9:.3f}: corrupt message skipped ({exc})"
            self.stats.warnings.append(line)
            log.warning(line)
            return None

    def scans(self, start: int = 0) -> Iterator[Scan]:
        for k, (time_ns, raw) in enumerate(self._raw_messages()):
            if k < start:  # skipped without decoding
                continue
            self.stats.messages += 1
            scan = self._decode(raw, time_ns)
            if scan is not None:
                scan = check_scan(scan, self.stats, f"{self.path} {self.topic}")
            if scan is not None:
                self.stats.scans += 1
                yield scan

    def _report(self, why: str, index) -> None:
        """Log and record what a walk over a damaged bag (ros1/mcap salvage index) found:
        one line for the walk, one per byte range lost mid-file, one for a lost end."""
        lines = [f"{self.path}: {why}; found {len(index.entries)} messages by walking the file"]
        lines += [f"{self.path}: skipped {loss.describe()}" for loss in index.losses]
        self.stats.damaged_chunks = len(index.losses)
        self.stats.lost_bytes = index.lost_bytes
        if index.damaged:
            tail = index.tail_bytes
            pct = 100.0 * tail / max(index.size, 1)
            sizes = [e[4] for e in index.entries]
            lost_msgs = tail / np.mean(sizes) if sizes else 0.0
            about = f", about {lost_msgs:.0f} messages" if lost_msgs >= 0.5 else ""
            lines.append(
                f"{self.path}: {index.reason}: lost {tail} of {index.size} bytes "
                f"({pct:.1f} %{about}) at the end, from byte {index.end_of_data}"
            )
        for line in lines:
            self.stats.warnings.append(line)
            log.warning(line)

    def _resume(self, salvage, done: list[int]) -> Iterator[tuple[int, bytes]]:
        """Messages of a salvage walk not yet yielded (`done`: their stamps, with repeats);
        what neither the reader nor the walk recovered is counted as skipped."""
        seen = collections.Counter(done)
        got = len(done)
        for time_ns, raw in self._salvaged(salvage):
            if seen[time_ns] > 0:
                seen[time_ns] -= 1
                continue
            got += 1
            yield time_ns, raw
        self.stats.skipped += max(len(self) - got, 0)

    def _check_livox_layout(self) -> None:
        """Livox points are read from the bytes: refuse a stored definition of another layout."""
        if self._salvage is not None:
            return  # a damaged bag: no definition to check, the decoder checks sizes
        with self._open() as reader:
            conn = next(c for c in reader.connections if c.topic == self.topic)
            if not layout_matches(conn.msgdef.data):
                raise InputError(
                    f"{self.path}: {self.topic} is a {self.msgtype} of another layout than the "
                    "Livox driver's (header, timebase, point_num, lidar_id, rsvd, points)"
                )

    def fields(self) -> dict[str, str]:
        if self.msgtype in (VELODYNE_SCAN, *CUSTOM_MSG_TYPES):
            return dict(VELODYNE_FIELDS_DECODED)
        for time_ns, raw in self._raw_messages():
            try:
                return describe_fields(self._deserialize(raw).fields)
            except Exception:  # noqa: BLE001, S112 - look at the next message
                log.debug("%s: message at %d not decodable", self.path, time_ns)
        return {}


class Ros1BagSource(_BagSource):
    """ROS1 .bag via rosbags; a bag without a usable index, or with a chunk rosbags cannot
    read, is walked record by record (ros1_salvage) and its damage reported in `stats`."""

    format = "ros1"

    def _read_topics(self) -> list[TopicInfo]:
        from forestslam.io import ros1_salvage

        self._store = _typestore(True)
        self._salvage = None
        try:
            with self._open() as reader:
                return [
                    TopicInfo(name, info.msgtype or "?", info.msgcount)
                    for name, info in sorted(reader.topics.items())
                ]
        except (PermissionError, IsADirectoryError) as exc:
            raise InputError(f"{self.path}: cannot open ({exc})") from None
        except Exception as exc:  # noqa: BLE001 - a damaged index makes rosbags raise anything
            with self.path.open("rb") as f:
                if f.read(len(ros1_salvage.MAGIC)) != ros1_salvage.MAGIC:
                    raise InputError(f"{self.path}: not a ROS1 bag ({_why(exc)})") from None
            self._salvage = self._walk(f"bag index unusable ({_why(exc)})")
        by_topic: dict[str, TopicInfo] = {}
        for conn in self._salvage.index.connections.values():
            msgtype = _normalize_msgtype(conn.msgtype)
            t = by_topic.setdefault(conn.topic, TopicInfo(conn.topic, msgtype, 0))
            t.count += conn.count
        return sorted(by_topic.values(), key=lambda t: t.name)

    def _walk(self, why: str):
        """Index the bag by walking its records; warn about everything that was lost."""
        from forestslam.io import ros1_salvage

        index = ros1_salvage.build_index(self.path)
        self._report(why, index)
        return ros1_salvage.SalvageReader(self.path, index)

    def _ids(self, salvage) -> set[int]:
        return {c.conn for c in salvage.index.connections.values() if c.topic == self.topic}

    def _salvaged(self, salvage) -> Iterator[tuple[int, bytes]]:
        for _conn, time_ns, raw in salvage.messages(self._ids(salvage)):
            yield time_ns, raw

    def _open(self):
        from rosbags.rosbag1 import Reader

        return Reader(self.path)

    def _deserialize(self, raw):
        return self._store.deserialize_ros1(raw, self.msgtype)


def _why(exc: BaseException) -> str:
    """An exception as text, with its type when its message says nothing (AssertionError)."""
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _normalize_msgtype(name: str) -> str:
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else name


class Ros2BagSource(_BagSource):
    """ROS2 bag: a directory with metadata.yaml, or a single .db3 or .mcap storage file."""

    def __init__(self, path: Path, topic: str | None, packets: PacketConfig | None = None) -> None:
        self.format = "ros2-" + ("dir" if path.is_dir() else path.suffix.lstrip(".").lower())
        super().__init__(path, topic, packets)

    def _open(self):
        from rosbags.rosbag2 import Reader

        return Reader(self.path)

    def _read_topics(self) -> list[TopicInfo]:
        self._store = _typestore(False)
        self._salvage = None
        try:
            with self._open() as reader:
                return [
                    TopicInfo(name, info.msgtype or "?", info.msgcount)
                    for name, info in sorted(reader.topics.items())
                ]
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types here
            if not self._is_mcap_file():
                raise InputError(f"{self.path}: cannot read ROS2 bag ({_why(exc)})") from None
            self._salvage = self._walk(f"MCAP summary unusable ({_why(exc)})")
        by_topic: dict[str, TopicInfo] = {}
        for ch in self._salvage.index.channels.values():
            t = by_topic.setdefault(ch.topic, TopicInfo(ch.topic, ch.msgtype, 0))
            t.count += ch.count
        return sorted(by_topic.values(), key=lambda t: t.name)

    def _can_walk(self) -> bool:
        return self._is_mcap_file()

    def _is_mcap_file(self) -> bool:
        from forestslam.io.mcap_salvage import MAGIC

        if not self.path.is_file():
            return False
        with self.path.open("rb") as f:
            return f.read(len(MAGIC)) == MAGIC

    def _walk(self, why: str):
        from forestslam.io import mcap_salvage

        index = mcap_salvage.build_index(self.path)
        self._report(why, index)
        return mcap_salvage.McapSalvageReader(self.path, index)

    def _ids(self, salvage) -> set[int]:
        return {c.id for c in salvage.index.channels.values() if c.topic == self.topic}

    def _salvaged(self, salvage) -> Iterator[tuple[int, bytes]]:
        for _ch, time_ns, raw in salvage.messages(self._ids(salvage)):
            yield time_ns, raw

    def _deserialize(self, raw):
        return self._store.deserialize_cdr(raw, self.msgtype)
