"""Levelling one session's frame on another's by the trees' heights.

Each run's frame is its first scan's sensor frame, tilted by the slope and sway where it
started. A planar (x, y, yaw) placement of one run in another's map leaves that tilt between
them, so a trajectory and the trees it observed land apart by tilt x height difference (over
terrain relief, centimetres to decimetres). Breast-height tree centres, known in both frames,
carry the tilt: a 3D rigid fit of the matched centres removes it.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from forestslam.geometry import rigid_fit, transform_points

log = logging.getLogger(__name__)


def level_fit(
    src: np.ndarray, dst: np.ndarray, min_trees: int, max_tilt_deg: float
) -> tuple[np.ndarray, float, int] | None:
    """T (4,4) with dst ~ T src for matched tree centres (N,3) (NaN heights are left out),
    refitted twice without the pairs beyond 3 robust sigmas; with its tilt (deg) and the pairs
    kept. None when fewer than `min_trees` pairs remain or the tilt is beyond `max_tilt_deg`
    (the heights do not describe one rigid motion)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    ok = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    src, dst = src[ok], dst[ok]
    if len(src) < min_trees:
        return None
    T, keep = rigid_fit(src, dst), np.ones(len(src), dtype=bool)
    for _ in range(2):
        r = np.linalg.norm(transform_points(T, src) - dst, axis=1)
        keep = r <= 3.0 * 1.4826 * max(float(np.median(r)), 1e-3)
        if keep.sum() < min_trees:
            return None
        T = rigid_fit(src[keep], dst[keep])
    tilt = math.degrees(math.acos(float(np.clip(T[2, 2], -1.0, 1.0))))
    if tilt > max_tilt_deg:
        log.warning("levelling: a %.1f deg tilt between the frames is implausible", tilt)
        return None
    return T, tilt, int(keep.sum())
