"""What a salvage walk over a damaged bag (ROS1 or MCAP) could not read, and how it is told."""

from __future__ import annotations

import collections
from dataclasses import dataclass, field


@dataclass
class Loss:
    """Bytes [start, end) mid-file that could not be read (fully), and the messages they held:
    `listed` by the index records after them, `found` all the same; `lost` per connection or
    channel (None: unknown, no index survived)."""

    start: int
    end: int
    what: str
    listed: list[tuple[int, int]] = field(default_factory=list)  # (connection, time_ns)
    found: list[tuple[int, int]] = field(default_factory=list)
    lost: dict[int, int] | None = None

    def describe(self) -> str:
        held = "the messages it held are unknown"
        if self.lost is not None:
            held = f"{sum(self.lost.values())} of {len(self.listed)} messages lost"
        size = self.end - self.start
        return f"bytes {self.start}-{self.end} ({size} bytes, {held}): {self.what}"


def count_losses(losses: list[Loss]) -> None:
    """Fill `lost` of every loss whose index survived: listed messages not found."""
    for loss in losses:
        if loss.listed:
            missing = collections.Counter(loss.listed) - collections.Counter(loss.found)
            loss.lost = dict(collections.Counter(conn for conn, _ in missing.elements()))
