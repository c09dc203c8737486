"""Checks every reader applies to a decoded scan before yielding it: what a driver or a
conversion got wrong is warned about once per input and counted in `ReadStats`, never passed
on silently.

- fewer than MIN_POINTS usable points (all NaN, all at the origin, a nearly empty message): the
  scan is skipped (`empty_scans`), so it never gets a pose of its own;
- per-point times beyond MAX_POINT_TIME_S from the stamp (after the reader made them relative:
  relative seconds, or nanoseconds since the epoch), or non-finite: the time field is dropped
  (`time_ignored`) and the scan is not deskewed;
- a ring field that is 0 on every point: dropped (`ring_ignored`), as if the driver gave none;
- a median range above MAX_PLAUSIBLE_RANGE_M (no LiDAR of this kind measures that far: the
  coordinates are in mm or cm, or the cloud is not in the sensor frame): kept, but warned with
  the probable cause (`implausible_range`).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from forestslam.io.scan import Scan
from forestslam.io.source import ReadStats

log = logging.getLogger(__name__)

MIN_POINTS = 10
MAX_POINT_TIME_S = 1.0  # 10 sweeps at 10 Hz, 5 at 5 Hz: more is not a time within a sweep
MAX_PLAUSIBLE_RANGE_M = 150.0  # a median range above this is not metres (ground dominates)
_UNITS = ((1000.0, "millimetres"), (100.0, "centimetres"))
_MIN_TYPICAL_RANGE_M = 1.0  # a median range in metres is rarely below this


def median_range(points: np.ndarray) -> float:
    """Median distance of the points from the sensor (on at most ~256 of them: enough to
    tell metres from millimetres)."""
    if len(points) == 0:
        return 0.0
    sample = points[:: max(1, len(points) // 256)]
    return float(np.median(np.sqrt(np.einsum("ij,ij->i", sample, sample))))


def median_spread(points: np.ndarray) -> float:
    """Median distance of the points from their median point (on at most ~256 of them)."""
    if len(points) == 0:
        return 0.0
    sample = points[:: max(1, len(points) // 256)]
    return float(np.median(np.linalg.norm(sample - np.median(sample, axis=0), axis=1)))


def unit_hint(range_m: float, spread_m: float, max_range_m: float = MAX_PLAUSIBLE_RANGE_M) -> str:
    """A hint when a scan's median range is implausible for a sensor reaching `max_range_m`
    (points in mm or cm, or not in the sensor frame at all), else ""."""
    if range_m <= max_range_m:
        return ""
    says = f"median range {range_m:.0f} m exceeds what the sensor measures ({max_range_m:.0f} m)"
    if spread_m <= max_range_m:  # close together, far away: a crop of a map or a georeference
        return (
            f"{says}, yet the points lie within {spread_m:.1f} m of each other: "
            "not a scan in the sensor frame?"
        )
    for factor, unit in _UNITS:
        if _MIN_TYPICAL_RANGE_M <= range_m / factor <= max_range_m:
            return f"{says}: are the coordinates in {unit}? Scale them to metres"
    return says


def _note(stats: ReadStats, kind: str, line: str) -> None:
    """Count one occurrence of `kind`; warn on the first one of the input only."""
    count = stats.degraded.get(kind, 0)
    stats.degraded[kind] = count + 1
    if count == 0:
        line += " (warned once; further scans counted in the read stats)"
        stats.warnings.append(line)
        log.warning(line)


def check_scan(scan: Scan, stats: ReadStats, where: str) -> Scan | None:
    """The scan as it may be used, or None when it has no usable points (see module doc)."""
    if len(scan) < MIN_POINTS:
        _note(
            stats,
            "empty_scans",
            f"{where} at t={scan.stamp:.3f}: {len(scan)} usable points (finite, not at the "
            f"origin), fewer than {MIN_POINTS}: scan skipped",
        )
        return None
    if scan.time is not None:
        t = scan.time
        biggest = float(np.max(np.abs(t))) if np.isfinite(t).all() else np.inf
        if biggest > MAX_POINT_TIME_S:
            _note(
                stats,
                "time_ignored",
                f"{where} at t={scan.stamp:.3f}: per-point times reach {biggest:.3g} s from the "
                f"stamp (more than {MAX_POINT_TIME_S} s, or not finite): time field ignored, "
                "scan not deskewed",
            )
            scan = replace(scan, time=None)
    if scan.ring is not None and not scan.ring.any():
        _note(
            stats,
            "ring_ignored",
            f"{where}: the ring field is 0 on every point: ignored, as if there were none",
        )
        scan = replace(scan, ring=None)
    range_m = median_range(scan.points)
    if range_m > MAX_PLAUSIBLE_RANGE_M:
        hint = unit_hint(range_m, median_spread(scan.points))
        _note(stats, "implausible_range", f"{where} at t={scan.stamp:.3f}: {hint}")
    return scan
