"""Damaged-bag benchmark (issue 19, items 1-2), one run on a simulated ROS1 bag:

1. `--flips` bags, each with one bit flipped in a field rosbags trusts (index-data `count`,
   chunk `size`, chunk data length), through `forestslam info` in this process: how many read,
   how many give a one-line error, how many a traceback.
2. One byte changed in the header of the middle chunk (its header length, or its `op` value):
   scans read of all, scans skipped, and the reader's warnings (where the loss is).

Run it with this tree's sources, then with an older tree's on PYTHONPATH, to compare.
Usage: python bench/damaged_bags.py BAG [--flips 40] [--out DIR]
(BAG: e.g. `forestslam simulate --scenario sample --max-scans 60 --out DIR`'s sequence.bag).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import random
import struct
import sys
import tempfile
from pathlib import Path


def records(data: bytes) -> list[tuple[int, int, bytes, int]]:
    """Top-level records of a sound bag: (op, start, header bytes, data length)."""
    from forestslam.io import ros1_salvage as rs

    out, pos = [], len(rs.MAGIC)
    while pos < len(data):
        (hlen,) = struct.unpack_from("<I", data, pos)
        header = data[pos + 4 : pos + 4 + hlen]
        (dlen,) = struct.unpack_from("<I", data, pos + 4 + hlen)
        out.append((rs._parse_header(header)["op"][0], pos, header, dlen))
        pos += 8 + hlen + dlen
    return out


def info_outcome(path: Path) -> str:
    from forestslam.cli.main import main

    sys.argv = ["forestslam", "-q", "info", str(path), "--json"]
    try:
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            main()
    except SystemExit as exc:
        return "read" if exc.code == 0 else "one-line error"
    except BaseException:  # noqa: BLE001 - what is measured
        return "traceback"
    return "read"


def flips(data: bytes, n: int, out: Path) -> dict[str, int]:
    from forestslam.io import ros1_salvage as rs

    targets = []
    for op, start, header, _ in records(data):
        if op == rs.OP_INDEX:
            targets.append(start + 4 + header.index(b"count=") + 6)
        if op == rs.OP_CHUNK:
            targets += [start + 4 + header.index(b"size=") + 5, start + 4 + len(header)]
    rng = random.Random(0)
    counts = {"read": 0, "one-line error": 0, "traceback": 0}
    for _ in range(n):
        damaged = bytearray(data)
        damaged[rng.choice(targets) + rng.randrange(4)] ^= 1 << rng.randrange(8)
        path = out / "flipped.bag"
        path.write_bytes(bytes(damaged))
        counts[info_outcome(path)] += 1
    return counts


def chunk_header(data: bytes, out: Path) -> None:
    from forestslam.io import read_scans
    from forestslam.io import ros1_salvage as rs

    total = sum(1 for _ in read_scans(out / "sound.bag"))
    chunks = [start for op, start, _, _ in records(data) if op == rs.OP_CHUNK]
    victim = chunks[len(chunks) // 2]
    for name in ("header length", "op value"):
        damaged = bytearray(data)
        at = victim + 1 if name == "header length" else data.index(b"op=", victim) + 3
        damaged[at] ^= 0x40 if name == "header length" else 0xFF
        path = out / "one_byte.bag"
        path.write_bytes(bytes(damaged))
        stream = read_scans(path)
        n = sum(1 for _ in stream)
        print(
            f"one byte of chunk {len(chunks) // 2}/{len(chunks)} ({name}): read {n} of {total} "
            f"scans, skipped {stream.stats.skipped}"
        )
        for line in stream.stats.warnings:
            print("   ", line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--flips", type=int, default=40)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    out = args.out or Path(tempfile.mkdtemp(prefix="damaged-bags-"))
    out.mkdir(parents=True, exist_ok=True)
    data = args.bag.read_bytes()
    (out / "sound.bag").write_bytes(data)
    counts = flips(data, args.flips, out)
    print(f"{args.flips} bags with one flipped bit in a length/count field: {counts}")
    chunk_header(data, out)


if __name__ == "__main__":
    main()
