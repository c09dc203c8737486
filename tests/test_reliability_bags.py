"""Damaged bags of the simulated sample sequence: a damaged index or length field never raises
anything but InputError, and one damaged chunk costs that chunk only, reported where it is."""

from __future__ import annotations

import struct

import numpy as np
from sim_bags import sample_sequence

from forestslam.io import read_scans
from forestslam.io import ros1_salvage as rs


def _records(data: bytes) -> list[tuple[int, int, bytes, int, int]]:
    """Top-level records of a sound bag: (op, start, header bytes, data start, end)."""
    out, pos = [], len(rs.MAGIC)
    while pos < len(data):
        (hlen,) = struct.unpack_from("<I", data, pos)
        header = data[pos + 4 : pos + 4 + hlen]
        (dlen,) = struct.unpack_from("<I", data, pos + 4 + hlen)
        op = rs._parse_header(header)["op"][0]
        out.append((op, pos, header, pos + 8 + hlen, pos + 8 + hlen + dlen))
        pos += 8 + hlen + dlen
    return out


def _length_fields(data: bytes) -> dict[str, list[int]]:
    """File offsets of the redundant fields rosbags trusts: index-data `count`, chunk `size`
    (uncompressed length) and chunk data length."""
    out: dict[str, list[int]] = {"index count": [], "chunk size": [], "chunk length": []}
    for op, start, header, data_start, _ in _records(data):
        if op == rs.OP_INDEX:
            out["index count"].append(start + 4 + header.index(b"count=") + 6)
        if op == rs.OP_CHUNK:
            out["chunk size"].append(start + 4 + header.index(b"size=") + 5)
            out["chunk length"].append(data_start - 4)
    return out


def test_damaged_index_count_or_chunk_length_is_read_in_full(tmp_path):
    """One flipped bit in a field rosbags trusts made it raise AssertionError or struct.error
    while opening (25 of 40 such bags of the 60-scan sample): now every bag is read in full."""
    path = sample_sequence("bag")
    truth = [s.stamp for s in read_scans(path)]
    data = path.read_bytes()
    fields = _length_fields(data)
    assert len(fields["index count"]) == len(fields["chunk size"]) >= 4
    rng = np.random.default_rng(19)
    for k in range(24):
        kind = list(fields)[k % 3]
        offset = fields[kind][rng.integers(len(fields[kind]))] + int(rng.integers(4))
        damaged = bytearray(data)
        damaged[offset] ^= 1 << int(rng.integers(8))
        bad = tmp_path / "damaged.bag"
        bad.write_bytes(bytes(damaged))
        stream = read_scans(bad)
        assert [s.stamp for s in stream] == truth, (kind, offset)
        assert stream.stats.skipped == 0


def test_damaged_chunk_header_costs_that_chunk_only(tmp_path, caplog):
    """A chunk header that does not parse ended the walk: the scans of every later chunk were
    lost and reported 'at the end' (9 of 12 here). Now the walk resumes at the index data
    after the chunk, whose offsets also find the chunk's messages when their records survived;
    a message whose record is damaged too is lost, and counted."""
    path = sample_sequence("bag")
    scans = [s.stamp for s in read_scans(path)]
    data = path.read_bytes()
    chunks = [r for r in _records(data) if r[0] == rs.OP_CHUNK]
    index = rs.build_index(path)
    assert len(chunks) >= 4 and len(index.chunks) == len(chunks)
    for victim in (1, len(chunks) - 1):
        _, start, _, data_start, end = chunks[victim]
        in_chunk = sorted((e[3], e[0]) for e in index.entries if e[2] == victim)
        assert 2 <= len(in_chunk) <= 4  # ~3 scans per 1 MB chunk
        damaged = bytearray(data)
        damaged[start : start + 12] = b"\xff" * 12  # header length and the first field
        for wreck_first_message in (False, True):
            if wreck_first_message:  # the end of its record header: its time and length
                first = data_start + in_chunk[0][0]
                damaged[first - 12 : first] = b"\xff" * 12
            bad = tmp_path / "damaged.bag"
            bad.write_bytes(bytes(damaged))
            caplog.clear()
            stream = read_scans(bad)
            out = [s.stamp for s in stream]
            lost = [round(t * 1e9) for t in scans if t not in set(out)]
            assert lost == ([in_chunk[0][1]] if wreck_first_message else []), victim
            assert stream.stats.skipped == len(lost) and stream.stats.damaged_chunks == 1
            assert f"bytes {start}-" in caplog.text, caplog.text
            assert f"{len(lost)} of {len(in_chunk)} messages lost" in caplog.text


def _mcap_chunks(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of the chunk records of a sound MCAP file."""
    from forestslam.io import mcap_salvage as ms

    out, pos = [], len(ms.MAGIC)
    while pos + 9 <= len(data) - len(ms.MAGIC):
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        if data[pos] == ms.OP_CHUNK:
            out.append((pos, pos + 9 + length))
        pos += 9 + length
    return out


def test_mcap_damaged_chunk_length_or_header_costs_that_chunk_only(tmp_path, caplog):
    """A chunk whose record length is damaged was taken for the file's cut end: every later
    chunk was lost. Now the chunk's second length field, or the chunks and message indexes
    the summary lists, let the walk go on."""
    path = sample_sequence("mcap")
    scans = [s.stamp for s in read_scans(path)]
    data = path.read_bytes()
    chunks = _mcap_chunks(data)
    assert len(chunks) >= 4
    start, end = chunks[1]

    damaged = bytearray(data)
    damaged[start + 1 : start + 9] = struct.pack("<Q", 10**12)  # the record's length only
    bad = tmp_path / "length.mcap"
    bad.write_bytes(bytes(damaged))
    stream = read_scans(bad)
    assert [s.stamp for s in stream] == scans and stream.stats.skipped == 0

    damaged[start : start + 48] = b"\xff" * 48  # opcode, both lengths, compression
    bad = tmp_path / "header.mcap"
    bad.write_bytes(bytes(damaged))
    caplog.clear()
    stream = read_scans(bad)
    out = [s.stamp for s in stream]
    in_chunk = len(scans) - len(out)
    assert 1 <= in_chunk <= 4 and out[-1] == scans[-1]
    assert out == [t for t in scans if t in set(out)]
    assert stream.stats.skipped == in_chunk
    assert f"bytes {start}-{end}" in caplog.text, caplog.text
    assert f"{in_chunk} of {in_chunk} messages lost" in caplog.text
