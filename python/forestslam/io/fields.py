"""From a structured point array (any field names a driver uses) to a `Scan`.

Accepted field names, first match wins (matching ignores case):
- position: `x`, `y`, `z` (required).
- intensity: `intensity`, `i`, `reflectivity`, `signal`, `scalar_Intensity` (CloudCompare),
  `remission`.
- ring: `ring`, `channel`, `line`, `laser_id`.
- time: `time`, `t`, `timestamp`, `offset_time`, `time_offset`, `gps_time`, `gpstime`,
  `scalar_GpsTime`.
  Integer time fields are nanoseconds (Ouster `t`, Livox `offset_time`, uint64 stamps), float
  fields seconds (Velodyne `time`, Hesai/Robosense `timestamp`) unless larger than 1e14 (float
  nanoseconds since the epoch, Livox ROS2 `timestamp`). Times larger than 1e6 s are absolute
  and are made relative to the scan stamp (the stamp is the earliest point time when the
  container gives none or 0).
Points with a non-finite coordinate, and points exactly at the origin (how Ouster and other
drivers mark "no return" in organized clouds), are dropped with one mask applied to every array.
"""

from __future__ import annotations

import numpy as np

from forestslam.errors import InputError
from forestslam.io.scan import Scan

INTENSITY_NAMES = ("intensity", "i", "reflectivity", "signal", "scalar_intensity", "remission")
RING_NAMES = ("ring", "channel", "line", "laser_id")
TIME_NAMES = ("time", "t", "timestamp", "offset_time", "time_offset", "gps_time", "gpstime")
TIME_NAMES += ("scalar_gpstime",)
ABSOLUTE_TIME_S = 1e6  # larger per-point times are absolute (seconds since some epoch)
ABSOLUTE_NS = 1e14  # larger float times are nanoseconds since the epoch
MAX_EPOCH_S = 4.1e9  # year 2100: larger absolute times are garbage, kept as they are so that
# forestslam.io.checks drops the field (they must not become the scan's stamp)


def _find(names: tuple[str, ...], available: dict[str, str]) -> str | None:
    for name in names:
        if name in available:
            return available[name]
    return None


def _first_component(values: np.ndarray) -> np.ndarray:
    """A field with count > 1 arrives as (..., count): keep its first element."""
    return values.reshape(values.shape[0], -1)[:, 0] if values.ndim > 1 else values


def _beyond_any_epoch(values: np.ndarray) -> bool:
    """Whether per-point times exceed any absolute time, read as seconds or nanoseconds."""
    if len(values) == 0:
        return False
    if values.dtype.kind in "iu":
        return float(values.max()) * 1e-9 > MAX_EPOCH_S or float(values.min()) < -MAX_EPOCH_S
    with np.errstate(invalid="ignore"):
        biggest = float(np.nanmax(np.abs(values.astype(np.float64)), initial=0.0))
    seconds = biggest * 1e-9 if biggest > ABSOLUTE_NS else biggest
    return seconds > MAX_EPOCH_S


def relative_time(values: np.ndarray, stamp: float | None) -> tuple[np.ndarray, float]:
    """Per-point times (any dtype, see module doc) -> (seconds relative to stamp, stamp).

    A stamp of None or 0 (drivers that leave header.stamp empty) is replaced by the earliest
    absolute point time."""
    unknown = stamp is None or stamp == 0.0
    if _beyond_any_epoch(values):
        with np.errstate(invalid="ignore", over="ignore"):
            return values.astype(np.float64), 0.0 if stamp is None else stamp
    if values.dtype.kind in "iu":
        ns = values.astype(np.int64)
        if len(ns) and np.abs(ns).max() > ABSOLUTE_TIME_S * 1e9:
            base_ns = int(ns.min()) if unknown else int(round(stamp * 1e9))
            return (ns - base_ns).astype(np.float64) * 1e-9, base_ns * 1e-9
        return ns.astype(np.float64) * 1e-9, 0.0 if stamp is None else stamp
    seconds = values.astype(np.float64)
    biggest = np.abs(seconds).max() if len(seconds) else 0.0
    if not np.isfinite(biggest):
        biggest = np.nanmax(np.abs(seconds[np.isfinite(seconds)]), initial=0.0)
    if biggest > ABSOLUTE_NS:  # float nanoseconds since the epoch (e.g. Livox `timestamp`)
        base_ns = float(np.nanmin(seconds)) if unknown else stamp * 1e9
        return (seconds - base_ns) * 1e-9, base_ns * 1e-9
    if biggest > ABSOLUTE_TIME_S:
        base = float(np.nanmin(seconds)) if unknown else stamp
        return seconds - base, base
    return seconds, 0.0 if stamp is None else stamp


def scan_from_structured(
    arr: np.ndarray, stamp: float | None, where: str, keep: np.ndarray | None = None
) -> Scan:
    """Structured array (any shape; organized clouds are flattened row-major) -> finite Scan.

    `stamp` None: taken from absolute per-point times when present, else 0. `keep`: the
    row-major indices of the real points when the caller computed them already (in C++).
    """
    names = arr.dtype.names or ()
    available = {}
    for name in names:
        available.setdefault(name.lower(), name)
    missing = [c for c in "xyz" if c not in available]
    if missing:
        raise InputError(f"{where}: point fields {list(names)} lack {', '.join(missing)}")
    flat = arr.reshape(-1)
    if keep is None:  # mask on strided views of the records
        x, y, z = (_first_component(flat[available[c]]) for c in "xyz")
        with np.errstate(over="ignore", invalid="ignore"):
            keep = np.flatnonzero(np.isfinite(x + y + z) & ((x != 0) | (y != 0) | (z != 0)))
    # One gather of the kept records; np.take is ~10x faster than boolean indexing on records
    # of odd size (e.g. 22 bytes).
    kept = flat if len(keep) == len(flat) else np.take(flat, keep)
    points = np.empty((len(kept), 3), dtype=np.float64)
    for k, c in enumerate("xyz"):
        points[:, k] = _first_component(kept[available[c]])

    intensity = ring = time = None
    if (name := _find(INTENSITY_NAMES, available)) is not None:
        intensity = _first_component(kept[name]).astype(np.float32)
    if (name := _find(RING_NAMES, available)) is not None:
        ring = _first_component(kept[name]).astype(np.uint16)
    if (name := _find(TIME_NAMES, available)) is not None:
        time, stamp = relative_time(_first_component(kept[name]), stamp)
    return Scan(float(0.0 if stamp is None else stamp), points, intensity, ring, time)
