"""Read an MCAP file whose writer was killed (no summary, no footer, last chunk cut short).

`ros2 bag record` writes MCAP by default; when it dies the file ends mid-chunk. We walk the
records from the start: every complete chunk is read, the cut last chunk as far as its bytes go
(uncompressed, lz4 and zstd streams all allow it), and
every complete message is kept; what follows the last complete message is reported as lost.
"""

from __future__ import annotations

import logging
import mmap
import struct
from dataclasses import dataclass, field
from pathlib import Path

from forestslam.errors import InputError

log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")


@dataclass
class McapChannel:
    id: int
    topic: str
    msgtype: str
    encoding: str
    count: int = 0


@dataclass
class _Chunk:
    datapos: int
    datasize: int
    compression: str
    partial: bool


@dataclass
class McapIndex:
    """Messages found by walking: (log_time_ns, channel id, chunk id or -1, offset, length)."""

    size: int
    channels: dict[int, McapChannel] = field(default_factory=dict)
    chunks: list[_Chunk] = field(default_factory=list)
    entries: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    end_of_data: int = 0
    damaged: bool = False
    reason: str = ""
    bad_chunks: list[str] = field(default_factory=list)
    schemas: dict[int, str] = field(default_factory=dict)

    @property
    def lost_bytes(self) -> int:
        return max(self.size - self.end_of_data, 0) if self.damaged else 0


def _string(buf, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    if pos + 4 + n > len(buf):
        raise ValueError("string overruns its record")
    return bytes(buf[pos + 4 : pos + 4 + n]).decode(), pos + 4 + n


def _records(buf, start: int):
    """Yield (opcode, body start, body end) while records are complete in `buf`; a record cut
    short is yielded once with its declared end (> len(buf)) and ends the walk."""
    pos, end = start, len(buf)
    while pos + 9 <= end:
        op = buf[pos]
        (length,) = _U64.unpack_from(buf, pos + 1)
        body = pos + 9
        yield op, body, body + length
        if body + length > end:
            return
        pos = body + length


def decompress(data: bytes, compression: str, partial: bool) -> bytes:
    if compression == "":
        return data
    if compression == "lz4":
        import lz4.frame

        if partial:
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
        return lz4.frame.decompress(data)
    if compression == "zstd":
        try:
            from compression import zstd  # Python >= 3.14
        except ImportError:
            from backports import zstd  # rosbags' own dependency before 3.14
        return zstd.ZstdDecompressor().decompress(data) if partial else zstd.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


def _one(index: McapIndex, chunk_id: int, buf, op: int, body: int, end: int) -> None:
    """Index one schema, channel or message record (other opcodes are skipped)."""
    if op == OP_SCHEMA:
        (sid,) = _U16.unpack_from(buf, body)
        index.schemas[sid] = _string(buf, body + 2)[0]
    elif op == OP_CHANNEL:
        cid, sid = struct.unpack_from("<HH", buf, body)
        topic, pos = _string(buf, body + 4)
        encoding, _ = _string(buf, pos)
        msgtype = index.schemas.get(sid, "?")
        index.channels.setdefault(cid, McapChannel(cid, topic, msgtype, encoding))
    elif op == OP_MESSAGE:
        (cid,) = _U16.unpack_from(buf, body)
        (log_time,) = _U64.unpack_from(buf, body + 6)
        index.entries.append((log_time, cid, chunk_id, body + 22, end - body - 22))
    elif op == OP_CHUNK:
        raise ValueError("chunk inside a chunk")


def _inner(index: McapIndex, chunk_id: int, buf) -> tuple[int, str]:
    """Index the records of a decompressed chunk up to the first damaged one.
    Returns (bytes used, "" or what was wrong)."""
    used = 0
    try:
        for op, body, end in _records(buf, 0):
            if end > len(buf):
                break
            _one(index, chunk_id, buf, op, body, end)
            used = end
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        return used, f"damaged record at byte {used} ({exc})"
    return used, ""


def build_index(path: Path) -> McapIndex:
    with path.open("rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{path}: not an MCAP file (no MCAP magic)")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as blob:
            index = _walk(blob)
    index.entries = [e for e in index.entries if e[1] in index.channels]
    index.entries.sort(key=lambda e: e[0])
    for e in index.entries:
        index.channels[e[1]].count += 1
    if not index.channels:
        raise InputError(f"{path}: MCAP without summary and no readable channel ({index.reason})")
    return index


def _walk(blob) -> McapIndex:
    index = McapIndex(size=len(blob), end_of_data=len(MAGIC))
    try:
        for op, body, end in _records(blob, len(MAGIC)):
            cut = end > len(blob)
            if op == OP_FOOTER and not cut:  # a complete file: only the closing magic follows
                index.end_of_data = len(blob)
                break
            if op == OP_CHUNK:
                header = struct.unpack_from("<QQQI", blob, body)
                compression, pos = _string(blob, body + 28)
                (size,) = _U64.unpack_from(blob, pos)
                data_start = pos + 8
                partial = cut or data_start + size > len(blob)
                present = min(data_start + size, len(blob)) - data_start
                index.chunks.append(_Chunk(data_start, present, compression, partial))
                chunk_id = len(index.chunks) - 1
                try:
                    raw = decompress(blob[data_start : data_start + present], compression, partial)
                    used, problem = _inner(index, chunk_id, raw)
                    if not problem and not partial and used < len(raw):
                        problem = f"records end at byte {used} of {header[2]}"
                except Exception as exc:  # noqa: BLE001 - lz4/zstd raise several types
                    raw, used, problem = b"", 0, f"chunk does not decompress ({exc})"
                if partial:
                    share = used / len(raw) if raw else 0.0
                    index.end_of_data = data_start + int(present * share)
                    index.damaged, index.reason = True, "the last chunk is incomplete"
                    break
                if problem:
                    index.bad_chunks.append(f"chunk at byte {body - 9}: {problem}")
            elif not cut:
                _one(index, -1, blob, op, body, end)
            if cut:
                index.damaged, index.reason = True, "a record runs past the end of the file"
                break
            index.end_of_data = end
        else:
            if index.end_of_data < len(blob):
                index.damaged, index.reason = True, "the file ends inside a record header"
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        index.damaged = True
        index.reason = f"unreadable record after byte {index.end_of_data} ({exc})"
    return index


class McapSalvageReader:
    """Iterate (channel, log_time_ns, raw message bytes) of a walked MCAP in time order."""

    def __init__(self, path: Path, index: McapIndex) -> None:
        self.path, self.index = path, index

    def messages(self, channels: set[int]):
        cache: tuple[int, bytes] = (-2, b"")
        with self.path.open("rb") as f:
            for time_ns, cid, chunk_id, start, length in self.index.entries:
                if cid not in channels:
                    continue
                if chunk_id < 0:
                    f.seek(start)
                    yield self.index.channels[cid], time_ns, f.read(length)
                    continue
                if cache[0] != chunk_id:
                    c = self.index.chunks[chunk_id]
                    f.seek(c.datapos)
                    cache = (chunk_id, decompress(f.read(c.datasize), c.compression, c.partial))
                yield self.index.channels[cid], time_ns, cache[1][start : start + length]
