"""What every scan reader provides (a typing.Protocol) and what it reports while reading."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

from forestslam.io.scan import Scan


@dataclass
class TopicInfo:
    name: str
    msgtype: str
    count: int


@dataclass
class ReadStats:
    """Counters a reader keeps while yielding scans; the pipeline runner reports them.

    messages: messages (or files) read on the chosen topic; scans: scans yielded;
    skipped: corrupt or lost messages/files (each one logged); lost_bytes: bytes of a damaged
    bag that could not be read (mid-file and at the end; where: `warnings`); damaged_chunks:
    damaged chunks or records skipped mid-file (each a byte range in `warnings`); degraded:
    scans per kind of problem found in decoded scans (see forestslam.io.checks: empty_scans
    skipped, time_ignored, ring_ignored, implausible_range);
    warnings: one line per problem (per kind for `degraded`).
    """

    messages: int = 0
    scans: int = 0
    skipped: int = 0
    lost_bytes: int = 0
    damaged_chunks: int = 0
    degraded: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "messages": self.messages,
            "scans": self.scans,
            "skipped": self.skipped,
            "lost_bytes": self.lost_bytes,
            "damaged_chunks": self.damaged_chunks,
            "degraded": dict(self.degraded),
            "warnings": list(self.warnings),
        }


@runtime_checkable
class ScanSource(Protocol):
    """One input (bag, folder or file) opened for reading scans.

    format: short name ("ros1", "ros2-mcap", "pcd-folder", ...); topic: the chosen topic or
    None; stats: filled while `scans()` runs.
    """

    format: str
    path: Path
    topic: str | None
    stats: ReadStats

    def topics(self) -> list[TopicInfo]:
        """All topics of the container with message counts ([] for files and folders)."""
        ...

    def fields(self) -> dict[str, str]:
        """Point fields of the first scan: {name: datatype}."""
        ...

    def __len__(self) -> int:
        """Number of scans the source holds (messages on the topic, or files)."""
        ...

    def scans(self, start: int = 0) -> Iterator[Scan]:
        """Scans in time order, finite points only; the first `start` messages or files are
        skipped without being decoded."""
        ...
