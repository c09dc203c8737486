"""Progress of a batch on stderr: recordings done / failed / running / queued and scans per second.

On a terminal one status line is redrawn twice a second; otherwise (a log file, CI) one line is
printed every few seconds. A line per finished recording is printed either way.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class BatchProgress:
    def __init__(
        self, total: int, skipped: int, enabled: bool = True, stream: TextIO | None = None
    ):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = self.stream.isatty()
        self.interval_s = 0.5 if self.tty else 5.0
        self.total, self.skipped = total, skipped
        self.done = self.failed = self.scans = 0
        self.t0 = time.perf_counter()
        self._last = -float("inf")
        self._drawn = False

    def due(self) -> bool:
        return self.enabled and time.perf_counter() - self._last >= self.interval_s

    def finished(self, row: dict) -> None:
        """Count a finished recording and print its line."""
        if row["status"] == "ok":
            self.done += 1
            self.scans += row["scans"] or 0
            text = (
                f"{row['name']}: ok, {row['scans']} scans ({row['scans_per_s'] or 0:.1f} scans/s)"
            )
        else:
            self.failed += 1
            text = f"{row['name']}: failed: {row['error']}"
        self._print(text, status=False)

    def show(self, running: int, queued: int, running_scans: int = 0) -> None:
        """The status line; `running_scans`: scans the running recordings have checkpointed."""
        self._last = time.perf_counter()
        elapsed = self._last - self.t0
        scans = self.scans + running_scans
        rate = scans / elapsed if elapsed > 0 else 0.0
        skipped = f", {self.skipped} finished earlier" if self.skipped else ""
        self._print(
            f"batch: {self.done + self.failed}/{self.total} recordings "
            f"({self.done} done, {self.failed} failed, {running} running, {queued} queued"
            f"{skipped}); {scans} scans, {rate:.1f} scans/s in {elapsed:.0f} s",
            status=True,
        )

    def close(self) -> None:
        if self.enabled and self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()

    def _print(self, text: str, status: bool) -> None:
        if not self.enabled:
            return
        if self.tty:  # redraw the status line in place; event lines scroll above it
            self.stream.write("\r\033[K" + text + ("" if status else "\n"))
            self._drawn = status
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
