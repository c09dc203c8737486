"""Raw Velodyne packets into Scans: `.pcap` captures and `velodyne_msgs/VelodyneScan` messages.

Decoding is velodyne_decoder's (a maintained C++ decoder with the factory calibrations of the
VLP-16, VLP-32C, HDL-32E and others, single and dual return). The model comes from the sensor
profile's `packet_model` when given, else from the factory byte of each packet, so a capture
decodes without a profile. A spinning scan is cut where the azimuth crosses `cut_angle_deg`
(pcap; a VelodyneScan message is already one revolution). A Scan's stamp is its first packet's
time, per-point `time` is seconds after it, `ring` counts beams from the lowest up, and dual-return
packets give both returns (as the ROS driver's point cloud does).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.checks import check_scan
from forestslam.io.scan import Scan
from forestslam.io.source import ReadStats, TopicInfo

log = logging.getLogger(__name__)

PACKET_BYTES = 1206  # a Velodyne data packet's UDP payload
POSITION_PACKET_BYTES = 512  # GPS/position packets on port 8308: not point data
VELODYNE_SCAN = "velodyne_msgs/msg/VelodyneScan"
# Model names accepted in a sensor profile's `packet_model` (velodyne_decoder's Model enum).
PACKET_MODELS = ("VLP16", "PuckHiRes", "PuckLite", "VLP32C", "HDL32E")
# The factory byte (last byte of a data packet) of each model; 0 on old firmware (unknown).
_FACTORY_BYTE = {0x21: "HDL32E", 0x22: "VLP16", 0x24: "PuckHiRes", 0x28: "VLP32C"}
_SAME_PACKETS = {"PuckLite": "VLP16"}  # models that send another model's factory byte
# The fields a decoded packet scan carries ({name: datatype}, as `forestslam info` lists them).
FIELDS = {"x": "float64", "y": "float64", "z": "float64", "intensity": "float32"}
FIELDS |= {"ring": "uint16", "time": "float64"}


@dataclass(frozen=True)
class PacketConfig:
    """How packets are decoded: `model` (None: from each packet's factory byte) and where a
    spinning scan is cut (degrees of azimuth, None: velodyne_decoder's default)."""

    model: str | None = None
    cut_angle_deg: float | None = None

    def decoder_config(self):
        import velodyne_decoder as vd

        config = vd.Config()
        config.timestamp_first_packet = True  # a Scan's stamp is the start of its sweep
        if self.model is not None:
            if self.model not in PACKET_MODELS:
                raise InputError(
                    f"packet_model {self.model!r} is not supported; choose one of "
                    f"{', '.join(PACKET_MODELS)}"
                )
            config.model = getattr(vd.Model, self.model)
        if self.cut_angle_deg is not None:
            if not 0.0 <= self.cut_angle_deg < 360.0:
                raise InputError(f"cut angle must be in [0, 360) degrees, not {self.cut_angle_deg}")
            config.cut_angle = float(np.radians(self.cut_angle_deg))
        return config


def scan_from_decoded(stamp: float, cloud: np.ndarray) -> Scan:
    """A Scan from velodyne_decoder's contiguous (N, 8) array (x y z intensity time column ring
    return_type); points at the origin (no return) are dropped."""
    cloud = np.asarray(cloud)
    keep = np.any(cloud[:, :3] != 0.0, axis=1) & np.all(np.isfinite(cloud[:, :3]), axis=1)
    cloud = cloud[keep]
    return Scan(
        float(stamp),
        cloud[:, :3].astype(np.float64),
        intensity=cloud[:, 3].astype(np.float32),
        ring=cloud[:, 6].astype(np.uint16),
        time=cloud[:, 4].astype(np.float64),
    )


class PacketStream:
    """Packets in, Scans out: `push(stamp, payload)` returns a Scan when a revolution is done."""

    def __init__(self, config: PacketConfig = PacketConfig()) -> None:
        import velodyne_decoder as vd

        self._decoder = vd.StreamDecoder(config.decoder_config())
        self._model, self._checked = config.model, False

    def push(self, stamp: float, payload: bytes) -> Scan | None:
        if not self._checked:
            check_model(payload, self._model)
            self._checked = True
        result = self._decoder.decode(float(stamp), payload)
        return None if result is None else scan_from_decoded(result[0].host, result[1])

    def finish(self) -> Scan | None:
        result = self._decoder.finish()
        return None if result is None else scan_from_decoded(result[0].host, result[1])


def check_model(payload: bytes, model: str | None) -> None:
    """InputError when a packet's factory byte names another model than the profile's: decoding
    with the wrong beam table gives a plausible-looking but wrong cloud."""
    sent = _FACTORY_BYTE.get(payload[-1])
    if model is None or sent is None or _SAME_PACKETS.get(model, model) == sent:
        return
    raise InputError(
        f"the packets come from a {sent} (factory byte 0x{payload[-1]:02x}) but the sensor "
        f"profile decodes them as {model}: choose the matching --sensor"
    )


def decode_scan_message(msg, config: PacketConfig = PacketConfig()) -> Scan:
    """One `velodyne_msgs/VelodyneScan` message (one revolution of packets) as one Scan."""
    import velodyne_decoder as vd

    packets = vd.PacketVector()
    for packet in msg.packets:
        stamp = packet.stamp.sec + packet.stamp.nanosec * 1e-9
        data = np.asarray(packet.data, dtype=np.uint8)
        if len(data) != PACKET_BYTES:
            raise ValueError(f"a packet holds {len(data)} bytes, not {PACKET_BYTES}")
        if not len(packets):
            check_model(bytes(data), config.model)
        packets.append(vd.VelodynePacket(stamp, data))
    if not len(packets):
        raise ValueError("the message holds no packets")
    stamp, cloud = vd.ScanDecoder(config.decoder_config()).decode(packets)
    return scan_from_decoded(stamp.host, cloud)


def _pcap_payloads(path: Path, stats: ReadStats) -> Iterator[tuple[float, bytes]]:
    """(capture time, UDP payload) of every Velodyne data packet in a pcap. Other frames (ARP,
    position packets) are passed over; a capture whose end is cut or damaged is read up to the
    damage, with a warning and the lost bytes counted."""
    frames = _frames(path, stats)
    current = next(frames, None)
    while current is not None:
        following = next(frames, None)
        stamp, frame = current
        payload, complete = _udp_payload(frame)
        if len(payload) == PACKET_BYTES and complete:
            yield stamp, payload
        elif following is None and not complete:
            _truncated(path, stats, path.stat().st_size - len(frame), "cut packet")
        current = following


def _frames(path: Path, stats: ReadStats) -> Iterator[tuple[float, bytes]]:
    import dpkt

    with open(path, "rb") as f:
        try:
            reader = dpkt.pcap.Reader(f)
        except (ValueError, dpkt.dpkt.UnpackError) as exc:
            raise InputError(f"{path}: not a pcap capture ({exc})") from None
        frames = iter(reader)
        while True:
            try:
                yield next(frames)
            except StopIteration:
                return
            except (dpkt.dpkt.UnpackError, ValueError) as exc:
                _truncated(path, stats, f.tell(), f"damaged packet record ({exc})")
                return


def _udp_payload(frame: bytes) -> tuple[bytes, bool]:
    """The UDP payload of an Ethernet frame, and whether the frame holds all of it (a capture
    cut mid-packet leaves fewer bytes than the UDP header announces)."""
    import dpkt

    try:
        ip = dpkt.ethernet.Ethernet(frame).data
        udp = ip.data if isinstance(ip, dpkt.ip.IP) else None
    except (dpkt.dpkt.UnpackError, ValueError):
        return b"", False
    if not isinstance(udp, dpkt.udp.UDP):
        return b"", True
    payload = bytes(udp.data)
    return payload, len(payload) + 8 >= udp.ulen


def _truncated(path: Path, stats: ReadStats, offset: int, why: str) -> None:
    size = path.stat().st_size
    stats.lost_bytes = max(size - offset, 0)
    line = f"{path}: capture ends in a {why} at byte {offset} of {size}: read up to the damage"
    stats.warnings.append(line)
    log.warning(line)


class PcapSource:
    """A Velodyne `.pcap` capture (VeloView, tcpdump, Wireshark): one Scan per revolution."""

    format = "pcap"
    topic = None

    def __init__(self, path: Path, config: PacketConfig = PacketConfig()) -> None:
        self.path, self.config, self.stats = path, config, ReadStats()
        self._count: int | None = None
        first = next(_pcap_payloads(path, ReadStats()), None)
        if first is None:
            raise InputError(f"{path}: no Velodyne data packets ({PACKET_BYTES}-byte UDP payloads)")

    def topics(self) -> list[TopicInfo]:
        return []

    def fields(self) -> dict[str, str]:
        return dict(FIELDS)

    def __len__(self) -> int:
        """Revolutions in the capture, counted from the packets' azimuths without decoding."""
        if self._count is None:
            cut = np.radians(self.config.cut_angle_deg or 0.0) * 18000 / np.pi
            azimuths = [
                int.from_bytes(p[2:4], "little") for _, p in _pcap_payloads(self.path, ReadStats())
            ]
            shifted = (np.asarray(azimuths, dtype=np.int64) - int(round(cut))) % 36000
            self._count = int(np.count_nonzero(np.diff(shifted) < 0)) + (len(azimuths) > 0)
        return self._count

    def scans(self, start: int = 0) -> Iterator[Scan]:
        stream = PacketStream(self.config)
        k = 0
        for stamp, payload in _pcap_payloads(self.path, self.stats):
            scan = stream.push(stamp, payload)
            if scan is not None:
                k += 1
                if k > start and (scan := self._count_scan(scan)) is not None:
                    yield scan
        scan = stream.finish()
        if scan is not None and k + 1 > start and (scan := self._count_scan(scan)) is not None:
            yield scan

    def _count_scan(self, scan: Scan) -> Scan | None:
        """The revolution as forestslam.io.checks lets it through (None: no usable points)."""
        self.stats.messages += 1
        scan = check_scan(scan, self.stats, str(self.path))
        self.stats.scans += scan is not None
        return scan
