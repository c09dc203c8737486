"""Read a ROS1 bag without its index: what `rosbag reindex` allows after a killed recorder,
and what is left of a bag with damaged bytes.

A recorder that dies leaves `index_pos = 0` in the bag header, and its last chunk with a
header that still says 0 bytes (rosbag rewrites chunk headers when a chunk closes) or with data
cut short. We walk the records from the start: every complete chunk is read, the partial last
chunk is decompressed as far as its bytes go (uncompressed, bz2 and lz4 streams all allow it),
and every complete message record in it is kept. Everything after the last complete message
is reported as lost.

A damaged record mid-bag (a header that does not parse, a chunk length that does not lead to
the next record) does not end the walk: it resumes at the next anchor, a record that never
occurs inside a chunk (index data, chunk, chunk info), found by scanning for its `op` field.
Each skipped byte range is reported with the messages it held, counted from the index-data
records that follow it when they survived.
"""

from __future__ import annotations

import bz2
import logging
import mmap
import struct
from dataclasses import dataclass, field
from pathlib import Path

from forestslam.errors import InputError
from forestslam.io.salvage import Loss, count_losses

log = logging.getLogger(__name__)

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
U32 = struct.Struct("<I")
_TOP_OPS = (OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION)
COMPRESSIONS = (b"none", b"bz2", b"lz4")
MAX_HEADER = 1 << 16  # bytes; real record headers are < 200 bytes (a connection's ~ 10 kB)
MAX_CHUNK_HEADER = 128  # bytes; a chunk header (compression, op, size) is ~ 41
_OP_FIELD = b"\x04\x00\x00\x00op="  # the `op` field of every record header
_MAX_BEFORE_OP = 128  # header bytes before it (rosbag C++ sorts the fields by name)


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
    losses: list[Loss] = field(default_factory=list)  # byte ranges lost mid-bag

    @property
    def tail_bytes(self) -> int:
        """Bytes lost at the end (a cut or killed recording)."""
        return max(self.size - self.end_of_data, 0) if self.damaged else 0

    @property
    def lost_bytes(self) -> int:
        return self.tail_bytes + sum(loss.end - loss.start for loss in self.losses)

    def lost_messages(self, conns: set[int]) -> int:
        """Messages of these connections the damaged ranges mid-bag are known to have held."""
        return sum(n for loss in self.losses for c, n in (loss.lost or {}).items() if c in conns)


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


def _record_at(buf, pos: int):
    """(header, data start, data length, record end) of a record whose header parses at `pos`,
    else None. The data may run past the end of `buf` (a cut file)."""
    if pos < 0 or pos + 8 > len(buf):
        return None
    (hlen,) = U32.unpack_from(buf, pos)
    if hlen > MAX_HEADER or pos + 8 + hlen > len(buf):
        return None
    try:
        header = _parse_header(buf[pos + 4 : pos + 4 + hlen])
    except ValueError:
        return None
    if len(header.get("op", b"")) != 1:
        return None
    (dlen,) = U32.unpack_from(buf, pos + 4 + hlen)
    data_start = pos + 8 + hlen
    return header, data_start, dlen, data_start + dlen


def _u32(header: dict[str, bytes], name: str) -> int | None:
    value = header.get(name)
    return U32.unpack(value)[0] if value is not None and len(value) == 4 else None


def _is_anchor(buf, pos: int) -> bool:
    """Whether a complete record that never occurs inside a chunk (index data, chunk, chunk
    info) starts at `pos` with consistent fields: where a walk may resume."""
    rec = _record_at(buf, pos)
    if rec is None or rec[3] > len(buf):
        return False
    header, _, dlen, _ = rec
    op = header["op"][0]
    if op in (OP_INDEX, OP_CHUNK_INFO):
        count = _u32(header, "count")
        step = 12 if op == OP_INDEX else 8
        return _u32(header, "ver") == 1 and count is not None and dlen == step * count
    if op == OP_CHUNK:
        return header.get("compression") in COMPRESSIONS and _u32(header, "size") is not None
    return False


def _continues(buf, pos: int) -> bool:
    """Whether a chunk ending at `pos` is followed by a record that cannot be inside a chunk
    (so the chunk's length field is right), or by a connection record."""
    rec = _record_at(buf, pos)
    ops = (OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION)
    return rec is not None and rec[0]["op"][0] in ops and rec[3] <= len(buf)


def _next_anchor(buf, start: int) -> int | None:
    """The first anchor record at or after `start`: its header holds an `op` field (length 4:
    b"op=" and one byte) at most _MAX_BEFORE_OP bytes after the record's start."""
    hit = buf.find(_OP_FIELD, start + 4)
    while hit >= 0:
        for pos in range(max(start, hit - 4 - _MAX_BEFORE_OP), hit - 3):
            if _is_anchor(buf, pos):
                return pos
        hit = buf.find(_OP_FIELD, hit + 1)
    return None


def _index_entries(header: dict[str, bytes], data: bytes) -> list[tuple[int, int]]:
    """(conn, time_ns) of the messages an index-data record lists."""
    conn = _u32(header, "conn")
    if conn is None or len(data) % 12:
        return []
    times = struct.iter_unpack("<III", data)
    return [(conn, sec * 10**9 + nsec) for sec, nsec, _offset in times]


def _index_run(buf, pos: int) -> list[tuple[int, int, int]]:
    """(conn, time_ns, offset) of the messages the index-data records from `pos` on list."""
    out = []
    while _is_anchor(buf, pos) and (rec := _record_at(buf, pos))[0]["op"][0] == OP_INDEX:
        header, data_start, _, rec_end = rec
        conn = _u32(header, "conn")
        times = struct.iter_unpack("<III", buf[data_start:rec_end])
        out += [(conn, sec * 10**9 + nsec, offset) for sec, nsec, offset in times]
        pos = rec_end
    return out


def _message_at(buf, data_start: int, conn: int, time_ns: int, offset: int):
    """(data offset from data_start, data length) of the message record at data_start +
    offset when it is the one listed (its connection and time), else None."""
    rec = _record_at(buf, data_start + offset)
    if rec is None or rec[0]["op"][0] != OP_MSG or rec[3] > len(buf):
        return None
    header, msg_start, dlen, _ = rec
    stamp = header.get("time", b"")
    if _u32(header, "conn") != conn or len(stamp) != 8:
        return None
    sec, nsec = struct.unpack("<II", stamp)
    return (msg_start - data_start, dlen) if sec * 10**9 + nsec == time_ns else None


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
            return _finish(path, _Walk(blob).run())


def _finish(path: Path, index: SalvageIndex) -> SalvageIndex:
    count_losses(index.losses)
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


class _Walk:
    """One pass over the records. A record that does not parse, or a chunk whose length does
    not lead to a valid record, makes the walk resume at the next anchor record (index data,
    chunk or chunk info), so one damaged header costs one chunk, not the rest of the bag."""

    def __init__(self, blob) -> None:
        self.blob, self.index = blob, SalvageIndex(size=len(blob))
        self.owner: Loss | None = None  # what the index-data records that follow describe

    def run(self) -> SalvageIndex:
        pos, size = len(MAGIC), len(self.blob)
        while pos < size:
            rec = _record_at(self.blob, pos)
            op = rec[0]["op"][0] if rec else -1
            if op not in _TOP_OPS:
                pos = self._skip(pos, "unreadable record")
                continue
            header, data_start, _, rec_end = rec
            if op == OP_CHUNK:
                pos = self._chunk(header, data_start, rec_end)
                continue
            if rec_end > size:
                self._tail(pos, "a record runs past the end of the file")
                break
            if op == OP_CONNECTION:
                try:
                    conn = _connection(header, self.blob[data_start:rec_end])
                except (ValueError, KeyError, struct.error) as exc:
                    pos = self._skip(pos, f"damaged connection record ({exc})")
                    continue
                self.index.connections.setdefault(conn.conn, conn)
            elif op == OP_INDEX and self.owner is not None:
                self.owner.listed += _index_entries(header, self.blob[data_start:rec_end])
            if op != OP_INDEX:
                self.owner = None
            self.index.end_of_data = pos = rec_end
        return self.index

    def _skip(self, pos: int, what: str) -> int:
        """Resume after an unreadable record at `pos`; returns where (the end when none)."""
        resume = _next_anchor(self.blob, pos + 1)
        if resume is None:
            self._tail(pos, f"{what} at byte {pos}")
            return len(self.blob)
        loss = Loss(pos, resume, what)
        self.index.losses.append(loss)
        self.owner = loss
        self.index.end_of_data = resume
        self._rescue(loss)
        return resume

    def _rescue(self, loss: Loss) -> None:
        """Read the messages of an uncompressed chunk whose header was lost: the index data
        after it gives each message's offset from the chunk's data start, which lies within a
        header's length of the loss's start."""
        listed = _index_run(self.blob, loss.end)
        if not listed:
            return
        best: tuple[int, list] = (0, [])
        for data_start in range(loss.start + 8, min(loss.start + 8 + MAX_CHUNK_HEADER, loss.end)):
            found = [m for m in listed if _message_at(self.blob, data_start, *m) is not None]
            if len(found) > len(best[1]):
                best = (data_start, found)
        data_start, found = best
        if not found:
            return
        self.index.chunks.append(_Chunk(data_start, loss.end - data_start, "none", False))
        chunk_id = len(self.index.chunks) - 1
        for conn, time_ns, offset in found:
            start, length = _message_at(self.blob, data_start, conn, time_ns, offset)
            self.index.entries.append((time_ns, conn, chunk_id, start, length))
        loss.found = [(conn, time_ns) for conn, time_ns, _ in found]
        loss.what += f"; {len(found)} messages read from the chunk's data all the same"
        loss.end = data_start if len(found) == len(listed) else loss.end

    def _tail(self, pos: int, reason: str) -> None:
        self.index.damaged, self.index.reason = True, reason
        self.index.end_of_data = pos

    def _chunk(self, header: dict[str, bytes], data_start: int, rec_end: int) -> int:
        """Index one chunk record; returns where the next record starts."""
        blob, size = self.blob, len(self.blob)
        partial = False
        if rec_end == data_start or (rec_end != size and not _continues(blob, rec_end)):
            # The length field is damaged, or the file ends in this chunk (a killed recorder:
            # cut data, or a length never rewritten from 0). The next anchor ends the chunk.
            resume = _next_anchor(blob, data_start)
            rec_end, partial = (size, True) if resume is None else (resume, False)
        compression = header.get("compression", b"none").decode(errors="replace")
        chunk = _Chunk(data_start, rec_end - data_start, compression, partial)
        self.index.chunks.append(chunk)
        before = len(self.index.entries)
        try:
            raw = decompress(blob[data_start:rec_end], compression, partial)
        except Exception as exc:  # noqa: BLE001 - lz4/bz2 raise several types
            raw, used, problem = b"", 0, f"does not decompress ({exc})"
        else:
            used, problem = _read_chunk_records(self.index, len(self.index.chunks) - 1, raw)
        if partial:
            self._cut_chunk(chunk, raw, used)
            return size
        loss = Loss(data_start, rec_end, f"damaged chunk ({problem})")
        loss.found = [(e[1], e[0]) for e in self.index.entries[before:]]
        self.owner = loss
        if problem:
            self.index.bad_chunks.append(f"chunk at byte {data_start}: {problem}")
            self.index.losses.append(loss)
        self.index.end_of_data = rec_end
        return rec_end

    def _cut_chunk(self, chunk: _Chunk, raw: bytes, used: int) -> None:
        # Compressed bytes map to message bytes only roughly: estimate the lost share of the
        # partial chunk from the share of its output we could use.
        if not raw:
            end = chunk.datapos
        elif chunk.compression == "none":
            end = chunk.datapos + used
        else:
            end = chunk.datapos + int(chunk.datasize * used / len(raw))
        self._tail(end, "the last chunk is incomplete")


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
