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

import numpy as np

from forestslam.io import Scan
from forestslam.sensors import SensorProfile
from forestslam.sim.forest import FOLIAGE, GROUND, SHRUB

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
    def grouped(self) -> bool:
        """True when the groups are equal runs of consecutive rays (fast path)."""
        n, g = len(self.group), len(self.group_time)
        if n % g:
            return False
        return bool((self.group == np.repeat(np.arange(g), n // g)).all())


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


def intensity_model(
    surface: np.ndarray,
    cos_inc: np.ndarray,
    profile: SensorProfile,
    noise_rel: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Foliage (and shrubs) return above the profile's intensity threshold most of the time
    (about 95 %); bark, wood and ground stay well below it; brighter at normal incidence."""
    thr = profile.intensity_threshold if profile.intensity_threshold is not None else 100.0
    leafy = (surface == FOLIAGE) | (surface == SHRUB)
    base = np.where(leafy, 1.55, np.where(surface == GROUND, 0.25, 0.35))
    incidence = np.where(leafy, 1.0, 0.5 + 0.5 * cos_inc)
    spread = np.where(leafy, 0.21, noise_rel)
    value = thr * base * incidence * (1.0 + spread * rng.standard_normal(len(surface)))
    return np.clip(value, 0.0, 255.0).astype(np.float32)


def synthesize_scan(
    scene,
    pattern: ScanPattern,
    poses: np.ndarray,
    profile: SensorProfile,
    stamp: float,
    rng: np.random.Generator,
    cast_seed: int,
    intensity_noise_rel: float,
    labels: bool = False,
) -> Scan | tuple[Scan, np.ndarray, np.ndarray]:
    """One scan: poses (G,4,4) T_world_sensor at pattern.group_time. With labels=True also the
    per-point surface class (N,) uint8 (see forest.SURFACES) and object row (N,) int32 (the tree
    id for stems)."""
    rot = poses[:, :3, :3]
    n_groups = len(poses)
    if pattern.grouped:
        # Groups are equal runs of consecutive rays: one origin per group, one batched product.
        origins = np.ascontiguousarray(poses[:, :3, 3])
        local = pattern.dirs.reshape(n_groups, -1, 3)
        world = np.matmul(local, rot.transpose(0, 2, 1)).reshape(-1, 3)
    else:
        origins = np.ascontiguousarray(poses[pattern.group, :3, 3])
        world = np.einsum("nij,nj->ni", rot[pattern.group], pattern.dirs)
    rng_range, surface, obj, cos_inc = scene.cast(
        origins, np.ascontiguousarray(world), profile.range_min_m, profile.range_max_m, cast_seed
    )
    keep = np.isfinite(rng_range)
    if profile.dropout_rate > 0:
        keep &= rng.random(len(keep)) >= profile.dropout_rate
    idx = np.flatnonzero(keep)
    r = rng_range[idx] + profile.range_noise_m * rng.standard_normal(len(idx))
    points = pattern.dirs[idx] * r[:, None]
    intensity = intensity_model(surface[idx], cos_inc[idx], profile, intensity_noise_rel, rng)
    scan = Scan(
        stamp=float(stamp),
        points=points,
        intensity=intensity,
        ring=pattern.ring[idx],
        time=pattern.time[idx].astype(np.float64),
    )
    return (scan, surface[idx], obj[idx]) if labels else scan
