"""The local frame `tls-register` works in: a georeferenced reference (UTM: ~6000 km from its
frame's origin) is recentred once at load, the pipeline runs near the origin, and every product
is shifted back to the reference's frame on output, in float64.

Why: the C++ stages hold points as float32 (PCL), whose spacing at 6000 km is 0.5 m, so a
UTM reference does not register at all; near the origin it is 0.1 um. References already near
their frame's origin (a single scan in its scanner's frame) are left as they are (offset 0),
so their results stay bit for bit what they were."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# An axis on which the reference's bounding-box centre lies farther than this from 0 is
# recentred: float32 spacing at 1 km is 61 um, negligible against the 1 cm stem figures.
RECENTRE_BEYOND_M = 1000.0


@dataclass(frozen=True)
class LocalFrame:
    """offset (3,): the local frame's origin in the reference's frame, whole metres (so
    shifted coordinates stay exact in float64 down to the reference's own resolution)."""

    offset: np.ndarray

    @classmethod
    def identity(cls) -> LocalFrame:
        return cls(np.zeros(3))

    @classmethod
    def for_reference(cls, reference: np.ndarray) -> LocalFrame:
        """Per axis, the reference's (R,3) bounding-box centre rounded to whole metres when
        it lies beyond RECENTRE_BEYOND_M from 0 (UTM easting and northing; an elevation only
        when over 1 km); else 0 (the identity for a reference near its frame's origin)."""
        pts = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            return cls.identity()
        # column by column: numpy's axis-0 reduction of a narrow array is 10x slower
        lo = np.array([pts[:, k].min() for k in range(3)])
        hi = np.array([pts[:, k].max() for k in range(3)])
        centre = 0.5 * (lo + hi)
        if not np.all(np.isfinite(centre)):
            return cls.identity()
        return cls(np.where(np.abs(centre) > RECENTRE_BEYOND_M, np.round(centre), 0.0))

    @property
    def shifted(self) -> bool:
        return bool(np.any(self.offset != 0))

    def points_in(self, points: np.ndarray) -> np.ndarray:
        """Points (N,3) of the reference's frame in the local frame (the input when unshifted)."""
        return np.asarray(points, dtype=np.float64) - self.offset if self.shifted else points

    def points_out(self, points: np.ndarray) -> np.ndarray:
        """Points (N,3) of the local frame in the reference's frame."""
        return np.asarray(points, dtype=np.float64) + self.offset if self.shifted else points

    def xy_in(self, xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, dtype=np.float64).reshape(-1, 2) - self.offset[:2]

    def xy_out(self, xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, dtype=np.float64).reshape(-1, 2) + self.offset[:2]

    def pose_in(self, T_ref_sensor: np.ndarray | None) -> np.ndarray | None:
        """A pose (4,4) T_reference_sensor as T_local_sensor (None stays None)."""
        if T_ref_sensor is None:
            return None
        T = np.array(T_ref_sensor, dtype=np.float64)
        T[:3, 3] -= self.offset
        return T

    def poses_out(self, T_local_sensor: np.ndarray) -> np.ndarray:
        """Poses (P,4,4) T_local_sensor as T_reference_sensor."""
        T = np.array(T_local_sensor, dtype=np.float64).reshape(-1, 4, 4)
        T[:, :3, 3] += self.offset
        return T
