"""The registry of scan readers, chosen by file type, and `read_scans`.

- `x.bag`: ROS1 bag (rosbags; unindexed or truncated bags are walked chunk by chunk).
- `x.mcap`, `x.db3`, a folder with `metadata.yaml`: ROS2 bag (rosbags; an `.mcap` cut short by
  a killed recorder is walked chunk by chunk).
- `x.pcap`: raw Velodyne packets (forestslam.io.velodyne), one scan per revolution.
- a folder of `.pcd` / `.ply` / `.las` / `.laz` / `.bin` / `.npy` files: one scan per file.
- one such file: one scan.

Cloud files get their stamp from per-point absolute times when present (LAS GPS time, a PCD
`timestamp` field), else from a numeric file name (`1581791678.408339.pcd` seconds,
`1581791678408339000.pcd` nanoseconds), else from a `times.txt` (one stamp per line, KITTI) in
the folder or its parent, else from the file order at `rate_hz`.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.bags import BAG_SUFFIXES, Ros1BagSource, Ros2BagSource
from forestslam.io.checks import check_scan
from forestslam.io.clouds import CLOUD_READERS, read_cloud_array, why_missing
from forestslam.io.fields import scan_from_structured
from forestslam.io.scan import Scan
from forestslam.io.source import ReadStats, ScanSource, TopicInfo
from forestslam.io.velodyne import PacketConfig, PcapSource

log = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 10.0
_NUMBER = re.compile(r"^\d+(\.\d+)?$")


def _natural_key(path: Path) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _name_stamp(path: Path) -> float | None:
    """Seconds from a file name that is a timestamp, else None (an index such as 000042)."""
    stem = path.stem
    if not _NUMBER.match(stem):
        return None
    value = float(stem)
    if "." not in stem and value >= 1e17:
        return int(stem) * 1e-9
    if "." not in stem and value >= 1e14:
        return int(stem) * 1e-6
    return value if 1e8 <= value < 1e11 else None


class CloudFilesSource:
    """A folder of cloud files (one scan each), or a single cloud file."""

    def __init__(self, path: Path, rate_hz: float = DEFAULT_RATE_HZ) -> None:
        if rate_hz <= 0:
            raise InputError(f"rate must be positive, not {rate_hz}")
        self.path, self.topic, self.stats = path, None, ReadStats()
        if path.is_dir():
            files = [p for p in path.iterdir() if p.suffix.lower() in CLOUD_READERS]
            suffixes = sorted({p.suffix.lower() for p in files})
            if not files:
                raise InputError(
                    f"{path}: folder holds no point-cloud files "
                    f"({', '.join(sorted(CLOUD_READERS))}) and no ROS2 metadata.yaml"
                )
            if len(suffixes) > 1:
                counts = ", ".join(
                    f"{s} ({sum(p.suffix.lower() == s for p in files)})" for s in suffixes
                )
                raise InputError(f"{path}: folder mixes cloud file types: {counts}")
            self.format = f"{suffixes[0].lstrip('.')}-folder"
        else:
            files = [path]
            self.format = path.suffix.lower().lstrip(".")
        stamps = [_name_stamp(p) for p in files]
        if all(s is not None for s in stamps):
            order = np.argsort(stamps, kind="stable")
            self.files = [files[i] for i in order]
            self.stamps: list[float | None] = [stamps[i] for i in order]
        else:
            self.files = sorted(files, key=_natural_key)
            self.stamps = self._times_txt(path, len(self.files))
        self.rate_hz = rate_hz

    @staticmethod
    def _times_txt(path: Path, n: int) -> list[float | None]:
        folder = path if path.is_dir() else path.parent
        for candidate in (folder / "times.txt", folder.parent / "times.txt"):
            if candidate.is_file() and path.is_dir():
                try:
                    times = np.loadtxt(candidate, ndmin=1)
                except ValueError:
                    continue
                if times.ndim == 1 and len(times) == n:
                    return [float(t) for t in times]
                log.warning("%s has %d stamps for %d files: ignored", candidate, len(times), n)
        return [None] * n

    def topics(self) -> list[TopicInfo]:
        return []

    def __len__(self) -> int:
        return len(self.files)

    def fields(self) -> dict[str, str]:
        arr, _ = read_cloud_array(self.files[0])
        return {
            n: str(arr.dtype[n].base) + (f"[{arr.dtype[n].shape[0]}]" if arr.dtype[n].shape else "")
            for n in arr.dtype.names
        }

    def scans(self, start: int = 0) -> Iterator[Scan]:
        for k, (file, stamp) in enumerate(zip(self.files, self.stamps, strict=True)):
            if k < start:
                continue
            self.stats.messages += 1
            try:
                arr, file_stamp = read_cloud_array(file)
                if stamp is None:
                    stamp = file_stamp
                scan = scan_from_structured(arr, stamp, str(file))
                if stamp is None and file_stamp is None and scan.stamp == 0.0:
                    scan.stamp = k / self.rate_hz
            except InputError as exc:
                if len(self.files) == 1:
                    raise
                self.stats.skipped += 1
                self.stats.warnings.append(f"{exc}: skipped")
                log.warning("%s: skipped", exc)
                continue
            scan = check_scan(scan, self.stats, str(self.path))
            if scan is not None:
                self.stats.scans += 1
                yield scan


# The explicit registry: format name -> (does it handle this path?, how to open it).
SourceFactory = Callable[[Path, "str | None", float, PacketConfig], ScanSource]
READERS: dict[str, tuple[Callable[[Path], bool], SourceFactory]] = {
    "ros1": (
        lambda p: p.is_file() and p.suffix.lower() == ".bag",
        lambda p, topic, rate, packets: Ros1BagSource(p, topic, packets),
    ),
    "ros2": (
        lambda p: (
            (p.is_file() and p.suffix.lower() in (".mcap", ".db3"))
            or (p.is_dir() and (p / "metadata.yaml").is_file())
        ),
        lambda p, topic, rate, packets: Ros2BagSource(p, topic, packets),
    ),
    "pcap": (
        lambda p: p.is_file() and p.suffix.lower() == ".pcap",
        lambda p, topic, rate, packets: PcapSource(p, packets),
    ),
    "clouds": (
        lambda p: p.is_dir() or p.suffix.lower() in CLOUD_READERS,
        lambda p, topic, rate, packets: CloudFilesSource(p, rate),
    ),
}


def open_source(
    path: str | Path,
    topic: str | None = None,
    rate_hz: float = DEFAULT_RATE_HZ,
    packets: PacketConfig | None = None,
) -> ScanSource:
    """Open any supported input; InputError names the file and the problem. `packets`: how raw
    Velodyne packets are decoded (a sensor profile's `packet_config()`; default: by the packets'
    factory byte, cut at velodyne_decoder's default azimuth)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: {why_missing(path)}")
    for _name, (handles, factory) in READERS.items():
        if handles(path):
            source = factory(path, topic, rate_hz, packets or PacketConfig())
            if topic is not None and not source.topics():
                raise InputError(f"{path}: topic {topic} given, but the input has no topics")
            return source
    supported = ", ".join([*BAG_SUFFIXES, ".pcap", *sorted(CLOUD_READERS)])
    raise InputError(f"{path}: unsupported input type {path.suffix!r} (supported: {supported})")


class ScanStream(Iterator[Scan]):
    """Iterator over scans with the source's `stats` (skipped messages, lost bytes) and len()."""

    def __init__(self, source: ScanSource, start: int = 0) -> None:
        self.source = source
        self._it = source.scans(start)

    @property
    def stats(self) -> ReadStats:
        return self.source.stats

    def __len__(self) -> int:
        return len(self.source)

    def __iter__(self) -> ScanStream:
        return self

    def __next__(self) -> Scan:
        return next(self._it)


def read_scans(
    path: str | Path,
    topic: str | None = None,
    rate_hz: float = DEFAULT_RATE_HZ,
    start: int = 0,
    packets: PacketConfig | None = None,
) -> ScanStream:
    """Scans of a bag, folder or file in time order (see the module doc for formats).

    `start` skips that many messages/files without decoding them (len() still counts all).
    Raises InputError at once for a missing file, unknown type, or an ambiguous/wrong topic.
    Corrupt messages are skipped, logged and counted in `.stats`.
    """
    if start < 0:
        raise InputError(f"start must be >= 0, not {start}")
    return ScanStream(open_source(path, topic, rate_hz, packets), start)
