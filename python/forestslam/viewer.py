"""A live view of a run in the Rerun viewer (rerun-sdk): `--rerun` streams to a viewer it
spawns, `--rerun-save run.rrd` records to a file instead (open it with `rerun run.rrd`, or drop
it on the web viewer).

Entities, in the run's output frame (z up): `world/scan` (the latest scan, by height),
`world/stems` (its detected stems, to DBH), `world/trajectory` (the optimised path),
`world/sensor` (the sensor pose), `world/trees` (the tree map as 1.3 m stems drawn to DBH) and
`world/ground` (the ground map), on the timelines `scan` (index) and `time` (stamp).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import transform_points

log = logging.getLogger(__name__)

BREAST_HEIGHT_M = 1.3


class RerunView:
    """One recording; every method is cheap enough to call per scan (the scan is thinned)."""

    def __init__(self, spawn: bool = False, save: str | Path | None = None, max_points=20000):
        try:
            import rerun as rr
        except ImportError as exc:  # a broken install, rerun-sdk is a dependency
            raise InputError(f"the Rerun viewer is not available ({exc})") from None
        if not spawn and save is None:
            raise InputError("RerunView needs spawn=True or a file to save to")
        self._rr = rr
        self._stream = rr.RecordingStream("forestslam")
        if save is not None:
            save = Path(save)
            save.parent.mkdir(parents=True, exist_ok=True)
            self._stream.save(save)
        else:
            self._stream.spawn()
        self._max_points = max_points
        self._rng = np.random.default_rng(0)
        self._stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def _at(self, scan: int, stamp: float) -> None:
        self._stream.set_time("scan", sequence=int(scan))
        self._stream.set_time("time", duration=float(stamp))

    def scan(self, scan: int, stamp: float, T_world_sensor: np.ndarray, points: np.ndarray):
        """The scan's points (sensor frame), shown in the world at their pose."""
        rr = self._rr
        self._at(scan, stamp)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) > self._max_points:
            pts = pts[self._rng.choice(len(pts), self._max_points, replace=False)]
        world = transform_points(T_world_sensor, pts)
        self._stream.log("world/scan", rr.Points3D(world, colors=_height_colors(world[:, 2])))
        self._stream.log(
            "world/sensor",
            rr.Transform3D(translation=T_world_sensor[:3, 3], mat3x3=T_world_sensor[:3, :3]),
        )

    def stems(self, scan: int, stamp: float, centres_world: np.ndarray, dbh: np.ndarray) -> None:
        """The scan's stems: breast-height centres (K,3) in the world, DBH (K,) (NaN: none)."""
        self._at(scan, stamp)
        self._stream.log("world/stems", self._cylinders(centres_world, dbh, 0.4, (255, 80, 40)))

    def trajectory(self, scan: int, stamp: float, positions: np.ndarray) -> None:
        self._at(scan, stamp)
        self._stream.log(
            "world/trajectory", self._rr.LineStrips3D([np.asarray(positions, np.float64)])
        )

    def trees(self, scan: int, stamp: float, xyz: np.ndarray, dbh: np.ndarray) -> None:
        """The tree map: breast-height centres (M,3), stems drawn 2.6 m long to DBH."""
        self._at(scan, stamp)
        self._stream.log(
            "world/trees", self._cylinders(xyz, dbh, 2 * BREAST_HEIGHT_M, (60, 170, 60))
        )

    def ground(self, scan: int, stamp: float, points: np.ndarray) -> None:
        self._at(scan, stamp)
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        self._stream.log("world/ground", self._rr.Points3D(pts, colors=(150, 120, 90)))

    def close(self) -> None:
        self._stream.flush()
        self._stream.disconnect()

    def _cylinders(self, centres, dbh, length, colour):
        centres = np.asarray(centres, np.float64).reshape(-1, 3)
        d = np.asarray(dbh, np.float64).reshape(-1)
        radii = np.where(np.isfinite(d) & (d > 0), d / 2, 0.05)
        return self._rr.Cylinders3D(
            lengths=np.full(len(centres), length), radii=radii, centers=centres, colors=colour
        )


def _height_colors(z: np.ndarray) -> np.ndarray:
    """Colours from blue (low) to yellow (high) over the 2nd-98th height percentiles."""
    if len(z) == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    lo, hi = np.percentile(z, [2, 98])
    t = np.clip((z - lo) / max(hi - lo, 1e-6), 0, 1)[:, None]
    low, high = np.array([40, 60, 200.0]), np.array([250, 220, 40.0])
    return (low + t * (high - low)).astype(np.uint8)
