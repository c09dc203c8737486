"""map3d: scan-to-map refinement of keyframes by point-to-plane ICP on stem and ground points.

The local map holds the stem and ground points of the last `icp_local_map_keyframes` keyframes
in the map frame (placed with their optimised poses when they were added). A new keyframe's
points are registered onto it from the SLAM prediction (trees already did the coarse step)
with the registration engineer's ICP (`forestslam.registration.facade`); the result enters the
pose graph as a BetweenFactorPose2 from the previous keyframe (see
`LandmarkSlam.refine_hook`). Results that did not converge, are degenerate, or move the pose
more than `icp_max_correction_m` are rejected and counted.
"""

from __future__ import annotations

import logging
from collections import deque

import numpy as np

from forestslam.geometry import transform_points
from forestslam.mapping.config import MappingConfig
from forestslam.mapping.voxel import voxel_downsample

log = logging.getLogger(__name__)


class ScanToMapRefiner:
    def __init__(self, config: MappingConfig | None = None) -> None:
        from forestslam.registration import facade

        self.cfg = config or MappingConfig()
        self._reg = facade
        self._map: deque[np.ndarray] = deque(maxlen=max(1, self.cfg.icp_local_map_keyframes))
        self.accepted = 0
        self.rejected = 0

    def source_points(self, stems) -> np.ndarray:
        """Stem and ground points of a scan (sensor frame), voxel-downsampled."""
        parts = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in (stems.points or [])]
        ground = getattr(stems, "ground", None)
        if ground is not None:
            parts.append(np.asarray(ground, dtype=np.float64).reshape(-1, 3))
        if not parts:
            return np.zeros((0, 3))
        return voxel_downsample(np.concatenate(parts), self.cfg.icp_voxel_m)

    def refine(
        self, source: np.ndarray, T_init: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Register source (N,3) onto the local map from T_init (4,4) -> (T (4,4), cov (6,6))."""
        if not self._map or len(source) < 50:
            return None
        target = np.concatenate(list(self._map))
        if len(target) < 100:
            return None
        try:
            res = self._reg.icp_point_to_plane(self._reg.PlaneTarget(target), source, T_init)
        except Exception as exc:  # the C++ side reports bad input as exceptions
            log.debug("scan-to-map ICP failed: %s", exc)
            self.rejected += 1
            return None
        T = np.asarray(res.T_target_source)
        moved = float(np.linalg.norm(T[:3, 3] - T_init[:3, 3]))
        if not res.converged or res.degenerate or moved > self.cfg.icp_max_correction_m:
            self.rejected += 1
            return None
        self.accepted += 1
        cov = np.asarray(res.covariance, dtype=np.float64)
        return T, cov

    def add_keyframe(self, source: np.ndarray, T_map_sensor: np.ndarray) -> None:
        if len(source):
            self._map.append(transform_points(T_map_sensor, source))
