"""The unit every reader yields and every algorithm consumes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Scan:
    """One LiDAR scan.

    stamp: float seconds (start of the sweep for spinning sensors).
    points: (N,3) float64 C-contiguous, sensor frame, all finite.
    intensity: (N,) float32 or None.  ring: (N,) uint16 or None.
    time: (N,) float64 seconds relative to `stamp`, or None.
    """

    stamp: float
    points: np.ndarray
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float64).reshape(-1, 3)
        n = len(self.points)
        for name in ("intensity", "ring", "time"):
            value = getattr(self, name)
            if value is not None and len(value) != n:
                raise ValueError(f"Scan.{name} has {len(value)} values for {n} points")

    def __len__(self) -> int:
        return len(self.points)

    def select(self, mask: np.ndarray) -> Scan:
        """A new scan with the points selected by a boolean mask or index array."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]

        return Scan(
            self.stamp, self.points[mask], pick(self.intensity), pick(self.ring), pick(self.time)
        )
