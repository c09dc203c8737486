"""Read an MCAP file whose writer was killed (no summary, no footer, last chunk cut short).

`ros2 bag record` writes MCAP by default; when it dies the file ends mid-chunk. We walk the
records from the start: every complete chunk is read, the cut last chunk as far as its bytes go
(uncompressed, lz4 and zstd streams all allow it), and
every complete message is kept; what follows the last complete message is reported as lost.

A damaged record mid-file (an unknown opcode, a length that does not lead to the next record)
does not end the walk: it resumes at the next chunk listed by the summary's chunk indexes
(when the end of the file survived) or found by its compression name (lz4, zstd). Each
skipped byte range is reported with the messages it held, counted from the message-index
records that follow it.
"""

from __future__ import annotations

import logging
import mmap
import struct
from dataclasses import dataclass, field
from pathlib import Path

from forestslam.errors import InputError
from forestslam.io.salvage import Loss, count_losses

log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_DATA_END = 0x07, 0x08, 0x0F
_OPS = range(0x01, 0x10)  # every opcode the MCAP specification defines
_COMPRESSED_CHUNK = (b"\x03\x00\x00\x00lz4", b"\x04\x00\x00\x00zstd")  # at chunk body + 28
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
    losses: list[Loss] = field(default_factory=list)  # byte ranges lost mid-file

    @property
    def tail_bytes(self) -> int:
        """Bytes lost at the end (a cut or killed recording)."""
        return max(self.size - self.end_of_data, 0) if self.damaged else 0

    @property
    def lost_bytes(self) -> int:
        return self.tail_bytes + sum(loss.end - loss.start for loss in self.losses)

    def lost_messages(self, channels: set[int]) -> int:
        """Messages of these channels the damaged ranges mid-file are known to have held."""
        return sum(n for loss in self.losses for c, n in (loss.lost or {}).items() if c in channels)


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
            index = _Walk(blob).run()
    count_losses(index.losses)
    index.entries = [e for e in index.entries if e[1] in index.channels]
    index.entries.sort(key=lambda e: e[0])
    for e in index.entries:
        index.channels[e[1]].count += 1
    if not index.channels:
        raise InputError(f"{path}: MCAP without summary and no readable channel ({index.reason})")
    return index


def _record(buf, pos: int) -> tuple[int, int, int] | None:
    """(opcode, body start, body end) of a complete record with a defined opcode at `pos`."""
    if pos < 0 or pos + 9 > len(buf) or buf[pos] not in _OPS:
        return None
    body = pos + 9
    end = body + _U64.unpack_from(buf, pos + 1)[0]
    return (buf[pos], body, end) if end <= len(buf) else None


def _chunk_layout(buf, pos: int) -> tuple[str, int, int] | None:
    """(compression, records start, records end = chunk end) of a sound chunk at `pos`: its
    two length fields (the record's and the records') agree, or the records' one leads to a
    sound record (the record's length is damaged). None otherwise."""
    if pos < 0 or pos + 9 + 40 > len(buf) or buf[pos] != OP_CHUNK:
        return None
    try:
        compression, at = _string(buf, pos + 9 + 28)
        (size,) = _U64.unpack_from(buf, at)
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    if compression not in ("", "lz4", "zstd"):
        return None
    end = at + 8 + size
    if end == pos + 9 + _U64.unpack_from(buf, pos + 1)[0] and end <= len(buf):
        return compression, at + 8, end
    sound_next = end == len(buf) - len(MAGIC) or _record(buf, end) is not None
    return (compression, at + 8, end) if end < len(buf) and sound_next else None


def _summary_offsets(buf) -> list[int]:
    """Offsets of the chunks and message-index records the summary's chunk indexes list
    (empty when the end of the file is damaged or missing)."""
    footer = len(buf) - len(MAGIC) - 9 - 20
    if footer < len(MAGIC) or buf[footer] != OP_FOOTER or buf[len(buf) - len(MAGIC) :] != MAGIC:
        return []
    (start,) = _U64.unpack_from(buf, footer + 9)
    offsets, pos = [], start
    while len(MAGIC) <= pos < footer and (rec := _record(buf, pos)) is not None:
        op, body, end = rec
        if op == OP_CHUNK_INDEX and end - body >= 36:
            offsets.append(_U64.unpack_from(buf, body + 16)[0])
            (n,) = _U32.unpack_from(buf, body + 32)
            for at in range(body + 36, min(body + 36 + n, end) - 9, 10):
                offsets.append(_U64.unpack_from(buf, at + 2)[0])
        pos = end
    return sorted(offsets)


class _Walk:
    """One pass over the records, resuming after damage at the next known chunk."""

    def __init__(self, blob) -> None:
        self.blob, self.index = blob, McapIndex(size=len(blob), end_of_data=len(MAGIC))
        self.listed = _summary_offsets(blob)
        self.owner: Loss | None = None  # what the message-index records that follow describe

    def _next_anchor(self, start: int) -> int | None:
        """The first sound chunk or message index at or after `start` the summary lists, or
        the first sound compressed chunk (found by its compression name)."""
        blob, found = self.blob, []
        for p in self.listed:
            rec = _record(blob, p) if p >= start else None
            if rec and (rec[0] == OP_MESSAGE_INDEX or _chunk_layout(blob, p)):
                found.append(p)
                break
        for name in _COMPRESSED_CHUNK:
            hit = blob.find(name, start + 9 + 28)
            while hit >= 0 and _chunk_layout(blob, hit - 9 - 28) is None:
                hit = blob.find(name, hit + 1)
            if hit >= 0:
                found.append(hit - 9 - 28)
        return min(found, default=None)

    def run(self) -> McapIndex:
        pos, size = len(MAGIC), len(self.blob)
        while pos < size:
            if size - pos == len(MAGIC) and self.blob[pos:] == MAGIC:
                self.index.end_of_data = size
                break
            rec = _record(self.blob, pos)
            layout = _chunk_layout(self.blob, pos)
            if layout is None and (rec is None or rec[0] == OP_CHUNK):
                pos = self._skip(pos)
                continue
            try:
                if layout is not None:
                    end = self._chunk(pos, layout)
                elif rec[0] == OP_MESSAGE_INDEX:
                    end = self._message_index(rec[1], rec[2])
                else:
                    _one(self.index, -1, self.blob, *rec)
                    self.owner, end = None, rec[2]
            except (ValueError, struct.error, UnicodeDecodeError):
                pos = self._skip(pos)
                continue
            self.index.end_of_data = pos = end
        return self.index

    def _skip(self, pos: int) -> int:
        """Resume after an unreadable record at `pos`; returns where (the end when none)."""
        resume = self._next_anchor(pos + 1)
        if resume is None:
            self._cut(pos)
            return len(self.blob)
        loss = Loss(pos, resume, "unreadable record")
        self.index.losses.append(loss)
        self.owner = loss
        self.index.end_of_data = resume
        return resume

    def _cut(self, pos: int) -> None:
        """The file ends inside the record at `pos` (a killed writer), or past damage there."""
        blob, index = self.blob, self.index
        index.end_of_data, index.damaged = pos, True
        index.reason = f"unreadable record at byte {pos}"
        if pos + 9 > len(blob):
            index.reason = "the file ends inside a record header"
        elif blob[pos] == OP_CHUNK:
            self._cut_chunk(pos)
        elif blob[pos] in _OPS:
            index.reason = "a record runs past the end of the file"

    def _cut_chunk(self, pos: int) -> None:
        """Read the chunk at `pos` as far as its bytes go (a writer killed mid-chunk)."""
        blob, index = self.blob, self.index
        try:
            compression, at = _string(blob, pos + 9 + 28)
            (size,) = _U64.unpack_from(blob, at)
        except (ValueError, struct.error, UnicodeDecodeError):
            return
        data_start = at + 8
        present = max(min(data_start + size, len(blob)) - data_start, 0)
        index.chunks.append(_Chunk(data_start, present, compression, True))
        try:
            raw = decompress(blob[data_start : data_start + present], compression, True)
            used, _ = _inner(index, len(index.chunks) - 1, raw)
        except Exception:  # noqa: BLE001 - lz4/zstd raise several types
            raw, used = b"", 0
        share = used / len(raw) if raw else 0.0
        index.end_of_data = data_start + int(present * share)
        index.reason = "the last chunk is incomplete"

    def _chunk(self, pos: int, layout: tuple[str, int, int]) -> int:
        """Index one sound chunk; returns its end."""
        compression, data_start, data_end = layout
        end = data_end
        self.index.chunks.append(_Chunk(data_start, data_end - data_start, compression, False))
        before = len(self.index.entries)
        try:
            raw = decompress(self.blob[data_start:data_end], compression, False)
            used, problem = _inner(self.index, len(self.index.chunks) - 1, raw)
            if not problem and used < len(raw):
                problem = f"records end at byte {used} of {len(raw)}"
        except Exception as exc:  # noqa: BLE001 - lz4/zstd raise several types
            problem = f"chunk does not decompress ({exc})"
        loss = Loss(pos, end, f"damaged chunk ({problem})")
        loss.found = [(e[1], e[0]) for e in self.index.entries[before:]]
        self.owner = loss
        if problem:
            self.index.bad_chunks.append(f"chunk at byte {pos}: {problem}")
            self.index.losses.append(loss)
        return end

    def _message_index(self, body: int, end: int) -> int:
        """Note the messages a message-index record lists for the chunk before; its end."""
        if self.owner is None or end - body < 6:
            return end
        (cid,) = _U16.unpack_from(self.blob, body)
        (n,) = _U32.unpack_from(self.blob, body + 2)
        if body + 6 + n <= end and n % 16 == 0:
            times = struct.iter_unpack("<QQ", self.blob[body + 6 : body + 6 + n])
            self.owner.listed += [(cid, t) for t, _offset in times]
        return end


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
