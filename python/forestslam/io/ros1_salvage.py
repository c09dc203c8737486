"""Read a ROS1 bag without its index: what `rosbag reindex` allows after a killed recorder.

A recorder that dies leaves `index_pos = 0` in the bag header, and its last chunk with a
header that still says 0 bytes (rosbag rewrites chunk headers when a chunk closes) or with data
cut short. We walk the records from the start: every complete chunk is read, the partial last
chunk is decompressed as far as its bytes go (uncompressed, bz2 and lz4 streams all allow it),
and every complete message record in it is kept. Everything after the last complete message
is reported as lost.
"""

from __future__ import annotations

import bz2
import logging
import mmap
import struct
from dataclasses import dataclass, field
from pathlib import Path

from forestslam.errors import InputError

log = logging.getLogger(__name__)

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
U32 = struct.Struct("<I")


@dataclass
class SalvageConnection:
    conn: int
    topic: str
    msgtype: str
    msgdef: str
    md5sum: str
    count: int = 0


@dataclass
class _Chunk:
    datapos: int
    datasize: int  # bytes present in the file
    compression: str
    partial: bool


@dataclass
class SalvageIndex:
    """Messages found by walking the bag: (time_ns, conn, chunk id, data offset, data length)."""

    size: int
    connections: dict[int, SalvageConnection] = field(default_factory=dict)
    chunks: list[_Chunk] = field(default_factory=list)
    entries: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    end_of_data: int = 0  # file offset after the last complete record we could use
    damaged: bool = False
    reason: str = ""
    bad_chunks: list[str] = field(default_factory=list)  # chunks skipped mid-bag, and why

    @property
    def lost_bytes(self) -> int:
        return max(self.size - self.end_of_data, 0) if self.damaged else 0


def _parse_header(buf: bytes | memoryview) -> dict[str, bytes]:
    fields, pos, end = {}, 0, len(buf)
    while pos + 4 <= end:
        (n,) = U32.unpack_from(buf, pos)
        pos += 4
        if n > end - pos:
            raise ValueError("header field overruns its header")
        item = bytes(buf[pos : pos + n])
        pos += n
        name, sep, value = item.partition(b"=")
        if not sep:
            raise ValueError("header field without '='")
        fields[name.decode("latin-1")] = value
    return fields


def _records(buf: bytes | memoryview, start: int = 0):
    """Yield (header fields, data start, data length, record end) while records are complete."""
    pos, end = start, len(buf)
    while pos + 4 <= end:
        (hlen,) = U32.unpack_from(buf, pos)
        if pos + 4 + hlen + 4 > end:
            return
        header = _parse_header(buf[pos + 4 : pos + 4 + hlen])
        (dlen,) = U32.unpack_from(buf, pos + 4 + hlen)
        data_start = pos + 8 + hlen
        yield header, data_start, dlen, data_start + dlen
        pos = data_start + dlen


def decompress(data: bytes, compression: str, partial: bool) -> bytes:
    if compression == "none":
        return data
    if compression == "bz2":
        return bz2.BZ2Decompressor().decompress(data) if partial else bz2.decompress(data)
    if compression == "lz4":
        import lz4.frame

        if partial:
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


def _connection(header: dict[str, bytes], data: bytes) -> SalvageConnection:
    conn = U32.unpack(header["conn"])[0]
    info = _parse_header(data)
    return SalvageConnection(
        conn,
        header.get("topic", info.get("topic", b"")).decode(),
        info.get("type", b"").decode(),
        info.get("message_definition", b"").decode(errors="replace"),
        info.get("md5sum", b"").decode(),
    )


def _read_chunk_records(index: SalvageIndex, chunk_id: int, raw: bytes) -> tuple[int, str]:
    """Index the messages of one decompressed chunk up to the first damaged record.
    Returns (bytes of the chunk that were usable, "" or what was wrong)."""
    used = 0
    try:
        for header, data_start, dlen, rec_end in _records(raw):
            if rec_end > len(raw):
                break
            op = header.get("op", b"\0")[0]
            if op == OP_CONNECTION:
                conn = _connection(header, raw[data_start:rec_end])
                index.connections.setdefault(conn.conn, conn)
            elif op == OP_MSG:
                conn = U32.unpack(header["conn"])[0]
                sec, nsec = struct.unpack("<II", header["time"])
                index.entries.append((sec * 10**9 + nsec, conn, chunk_id, data_start, dlen))
            else:
                raise ValueError(f"record op {op} inside a chunk")
            used = rec_end
    except (ValueError, KeyError, struct.error, UnicodeDecodeError) as exc:
        return used, f"damaged record at chunk byte {used} ({exc})"
    if used < len(raw):
        return used, f"damaged record at chunk byte {used} of {len(raw)}"
    return used, ""


def build_index(path: Path) -> SalvageIndex:
    """Walk every record of the bag; raise InputError when not even the start is readable."""
    with path.open("rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{path}: not a ROS1 bag (no '#ROSBAG V2.0' magic)")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as blob:
            return _walk(path, blob)


def _walk(path: Path, blob: mmap.mmap) -> SalvageIndex:
    index = SalvageIndex(size=len(blob))
    pos = len(MAGIC)
    try:
        records = _records(blob, pos)
        for header, data_start, dlen, rec_end in records:
            op = header.get("op", b"\0")[0]
            if op == OP_CHUNK:
                compression = header.get("compression", b"none").decode()
                present = min(rec_end, len(blob)) - data_start
                partial = rec_end > len(blob) or (dlen == 0 and data_start < len(blob))
                if dlen == 0 and partial:  # header never rewritten: data runs to the end
                    present = len(blob) - data_start
                chunk = _Chunk(data_start, present, compression, partial)
                index.chunks.append(chunk)
                try:
                    raw = decompress(blob[data_start : data_start + present], compression, partial)
                except Exception as exc:  # noqa: BLE001 - lz4/bz2 raise several types
                    raw = b""
                    problem = f"chunk at byte {data_start} does not decompress ({exc})"
                else:
                    used, problem = _read_chunk_records(index, len(index.chunks) - 1, raw)
                if problem and not partial:
                    index.bad_chunks.append(problem)
                if partial:
                    # Compressed bytes map to message bytes only roughly: estimate the lost
                    # share of the partial chunk from the share of its output we could use.
                    if not raw:
                        index.end_of_data = data_start
                    elif compression == "none":
                        index.end_of_data = data_start + used
                    else:
                        share = used / len(raw) if len(raw) else 0.0
                        index.end_of_data = data_start + int(present * share)
                    index.damaged = True
                    index.reason = "the last chunk is incomplete"
                    break
                index.end_of_data = rec_end
            elif op == OP_CONNECTION:
                conn = _connection(header, blob[data_start:rec_end])
                index.connections.setdefault(conn.conn, conn)
                index.end_of_data = rec_end
            elif op in (OP_BAG_HEADER, OP_INDEX, OP_CHUNK_INFO):
                index.end_of_data = rec_end
            else:
                raise ValueError(f"unknown record op {op}")
            if rec_end > len(blob):
                index.damaged = True
                index.reason = "a record runs past the end of the file"
                break
        else:
            if index.end_of_data < len(blob):
                index.damaged = True
                index.reason = "the file ends inside a record"
    except (ValueError, KeyError, struct.error, OSError, EOFError) as exc:
        index.damaged = True
        index.reason = f"unreadable record after byte {index.end_of_data} ({exc})"
    # Messages whose connection record was lost cannot be decoded: drop them.
    index.entries = [e for e in index.entries if e[1] in index.connections]
    index.entries.sort(key=lambda e: e[0])
    counts: dict[int, int] = {}
    for e in index.entries:
        counts[e[1]] = counts.get(e[1], 0) + 1
    for conn in index.connections.values():
        conn.count = counts.get(conn.conn, 0)
    if not index.entries and not index.connections:
        raise InputError(f"{path}: ROS1 bag without index and no readable chunk ({index.reason})")
    return index


class SalvageReader:
    """Iterate (connection, time_ns, raw message bytes) of a walked bag in time order."""

    def __init__(self, path: Path, index: SalvageIndex) -> None:
        self.path, self.index = path, index

    def messages(self, conns: set[int]):
        cache: tuple[int, bytes] = (-1, b"")
        with self.path.open("rb") as f:
            for time_ns, conn, chunk_id, start, length in self.index.entries:
                if conn not in conns:
                    continue
                if cache[0] != chunk_id:
                    c = self.index.chunks[chunk_id]
                    f.seek(c.datapos)
                    cache = (chunk_id, decompress(f.read(c.datasize), c.compression, c.partial))
                yield self.index.connections[conn], time_ns, cache[1][start : start + length]
