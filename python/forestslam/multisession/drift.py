"""Drift injection for tests and benches: the odometry corrupted as a worse one would be.

Each step's translation is scaled by (1 + `scale`) and its heading turned by `yaw_deg_per_10m`
per 10 m travelled, so errors grow with distance as real odometry drift does (a 2 % scale error
and 1 deg per 10 m make 100 m of walking end metres off). Only the poses fed to the back end
change; the scans and stems do not.
"""

from __future__ import annotations

import math

import numpy as np


class DriftInjector:
    def __init__(self, scale: float = 0.02, yaw_deg_per_10m: float = 1.0) -> None:
        self.scale, self.yaw_per_m = scale, math.radians(yaw_deg_per_10m) / 10.0
        self._true: np.ndarray | None = None
        self._drifted: np.ndarray | None = None

    @classmethod
    def parse(cls, text: str) -> DriftInjector:
        """`scale,yaw_deg_per_10m`, e.g. `0.02,1.0`."""
        from forestslam.errors import InputError

        try:
            scale, yaw = (float(v) for v in text.split(","))
        except ValueError:
            raise InputError(
                f"--inject-drift must be scale,yaw_deg_per_10m, not {text!r}"
            ) from None
        return cls(scale, yaw)

    def apply(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """The drifted pose (4,4) for the next true odometry pose."""
        T = np.asarray(T_world_sensor, dtype=np.float64)
        if self._true is None:
            self._true, self._drifted = T.copy(), T.copy()
            return T.copy()
        step = np.linalg.inv(self._true) @ T
        step[:3, 3] *= 1.0 + self.scale
        dyaw = self.yaw_per_m * float(np.linalg.norm(step[:2, 3]))
        turn = np.eye(4)
        turn[:2, :2] = [[math.cos(dyaw), -math.sin(dyaw)], [math.sin(dyaw), math.cos(dyaw)]]
        self._true = T.copy()
        self._drifted = self._drifted @ turn @ step
        return self._drifted.copy()
