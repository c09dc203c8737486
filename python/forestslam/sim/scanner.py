"""Scan patterns of the sensor profiles and the synthesis of one `Scan` from the ray caster.

Spinning sensors fire one column of all beams at a time, sweeping clockwise (seen from above, as
Velodyne and Ouster do) from the rear over one revolution; solid-state sensors raster their field
row by row (alternate rows in opposite directions); a TLS station is one static dense dome. Each
point is expressed in the sensor frame at its own measurement time, like a real driver, and
`time` is relative to the scan stamp (= start of the sweep).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from forestslam.io import Scan
from forestslam.sensors import SensorProfile

# Groups of rays share one sensor pose (the platform pose is evaluated per group).
SOLID_STATE_GROUP = 31


@dataclass
class ScanPattern:
    dirs: np.ndarray  # (N,3) unit directions, sensor frame, in firing order
    ring: np.ndarray  # (N,) uint16 beam (spinning) or row index
    time: np.ndarray  # (N,) seconds since the sweep start
    group: np.ndarray  # (N,) index into group_time
    group_time: np.ndarray  # (G,)
    period_s: float  # time between scans (0 for a single static station)

    @cached_property
    def time64(self) -> np.ndarray:
        return self.time.astype(np.float64)

    @cached_property
    def knot_groups(self) -> np.ndarray:
        """Group rows at which poses are evaluated (about 1 ms apart over a sweep, first and
        last included); synthesize_scan interpolates between them. The platform's motion is
        smooth on that scale: sub-millimetre differences at 50 m."""
        g = len(self.group_time)
        step = max(1, g // 100)
        rows = np.arange(0, g, step)
        rows = rows if rows[-1] == g - 1 else np.append(rows, g - 1)
        # Knot times must increase strictly.
        return rows[np.concatenate([[True], np.diff(self.group_time[rows]) > 0])]


def _dirs(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    ce = np.cos(elevation)
    return np.column_stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)])


def make_pattern(profile: SensorProfile) -> ScanPattern:
    elev = profile.vertical_angles_rad
    if profile.kind == "spinning":
        cols = int(round(profile.horizontal_fov_deg / profile.azimuth_resolution_deg))
        period = 1.0 / profile.rate_hz
        az = np.pi - 2 * np.pi * np.arange(cols) / cols  # clockwise from the rear
        ring = np.tile(np.arange(len(elev), dtype=np.uint16), cols)
        group = np.repeat(np.arange(cols), len(elev))
        dirs = _dirs(np.tile(elev, cols), az[group])
        group_time = np.arange(cols) * period / cols
        return ScanPattern(dirs, ring, group_time[group], group, group_time, period)
    if profile.kind == "solid_state":
        rows, cols = profile.image_rows, profile.image_cols
        period = 1.0 / profile.rate_hz
        half = np.radians(profile.horizontal_fov_deg) / 2
        az = np.linspace(half, -half, cols)  # left to right
        el = np.radians(np.linspace(profile.vertical_fov_deg[1], profile.vertical_fov_deg[0], rows))
        r_idx = np.repeat(np.arange(rows), cols)
        c_idx = np.tile(np.arange(cols), rows)
        c_idx = np.where(r_idx % 2 == 1, cols - 1 - c_idx, c_idx)  # boustrophedon raster
        order = np.arange(rows * cols)
        time = order * period / (rows * cols)
        group = order // SOLID_STATE_GROUP
        n_groups = int(group[-1]) + 1
        group_time = (np.arange(n_groups) * SOLID_STATE_GROUP + SOLID_STATE_GROUP / 2) * (
            period / (rows * cols)
        )
        group_time = np.minimum(group_time, time[-1])
        ring = (rows - 1 - r_idx).astype(np.uint16)  # 0 = lowest row
        return ScanPattern(_dirs(el[r_idx], az[c_idx]), ring, time, group, group_time, period)
    if profile.kind == "tls":
        cols = int(round(profile.horizontal_fov_deg / profile.azimuth_resolution_deg))
        az = np.pi - 2 * np.pi * np.arange(cols) / cols
        ring = np.tile(np.arange(len(elev), dtype=np.uint16), cols)
        group = np.zeros(len(ring), dtype=np.int64)
        dirs = _dirs(np.tile(elev, cols), np.repeat(az, len(elev)))
        return ScanPattern(dirs, ring, np.zeros(len(ring)), group, np.zeros(1), 0.0)
    raise ValueError(f"sensor kind {profile.kind!r} cannot be simulated")


def synthesize_scan(
    scene,
    pattern: ScanPattern,
    poses: np.ndarray,
    model: Any,
    stamp: float,
    rng: np.random.Generator,
    cast_seed: int,
    labels: bool = False,
    pose_times: np.ndarray | None = None,
) -> Scan | tuple[Scan, np.ndarray, np.ndarray]:
    """One scan: poses (G,4,4) T_world_sensor at pattern.group_time, or at pose_times (M,)
    (increasing, seconds since the sweep start; interpolated to the group times, rotation by
    normalised quaternion interpolation). model: the measurement model (sensor_model.scan_model:
    ranges, noise, dropouts, per-material intensity). rng seeds the dropouts and the range and
    intensity noise (drawn in C++, one hash per ray). With labels=True also the per-point surface
    class (N,) uint8 (see forest.SURFACES) and object (N,) int32 (the tree id for stems)."""
    knot_time = pattern.group_time if pose_times is None else np.asarray(pose_times, np.float64)
    res = scene.synthesize(
        np.ascontiguousarray(knot_time, dtype=np.float64),
        np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 16)),
        pattern.group_time,
        pattern.group,
        pattern.dirs,
        model,
        int(cast_seed),
        int(rng.integers(0, 2**63)),
    )
    ray = res.ray
    scan = Scan(
        stamp=float(stamp),
        points=res.points,
        intensity=res.intensity,
        ring=pattern.ring[ray],
        time=pattern.time64[ray],
    )
    return (scan, res.surface, res.object) if labels else scan
