"""Drift injection for tests and benches: the odometry corrupted as a worse one would be.

Each step's translation is scaled by (1 + `scale`) and its heading turned by `yaw_deg_per_10m`
per 10 m travelled, so errors grow with distance as real odometry drift does (a 2 % scale error
and 1 deg per 10 m make 100 m of walking end metres off). A loss can be added: after `jump_at_m`
travelled, the odometry jumps once by `jump_m` sideways and `jump_deg` in heading (a tracking
failure). Only the poses fed to the back end change; the scans and stems do not.
"""

from __future__ import annotations

import math

import numpy as np

from forestslam.geometry import planar_pose


class DriftInjector:
    def __init__(
        self,
        scale: float = 0.02,
        yaw_deg_per_10m: float = 1.0,
        jump_at_m: float | None = None,
        jump_m: float = 0.0,
        jump_deg: float = 0.0,
    ) -> None:
        self.scale, self.yaw_per_m = scale, math.radians(yaw_deg_per_10m) / 10.0
        self.jump_at_m, self.jump_m, self.jump = jump_at_m, jump_m, math.radians(jump_deg)
        self.travelled = 0.0
        self._true: np.ndarray | None = None
        self._drifted: np.ndarray | None = None

    @classmethod
    def parse(cls, text: str) -> DriftInjector:
        """`scale,yaw_deg_per_10m[,jump_at_m,jump_m,jump_deg]`, e.g. `0.02,1.0` or
        `0,0,30,4,20`."""
        from forestslam.errors import InputError

        try:
            values = [float(v) for v in text.split(",")]
            if len(values) not in (2, 5) or not np.all(np.isfinite(values)):
                raise ValueError
        except ValueError:
            raise InputError(
                "--inject-drift must be scale,yaw_deg_per_10m[,jump_at_m,jump_m,jump_deg], "
                f"not {text!r}"
            ) from None
        if not -1.0 < values[0] < 1.0 or abs(values[1]) > 180.0:
            raise InputError(
                f"--inject-drift {text}: scale is a fraction in (-1, 1) (0.02 is 2 %) and "
                "yaw_deg_per_10m at most 180"
            )
        return cls(*values)

    def apply(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """The drifted pose (4,4) for the next true odometry pose."""
        T = np.asarray(T_world_sensor, dtype=np.float64)
        if self._true is None:
            self._true, self._drifted = T.copy(), T.copy()
            return T.copy()
        step = np.linalg.inv(self._true) @ T
        distance = float(np.linalg.norm(step[:2, 3]))
        self.travelled += distance
        step[:3, 3] *= 1.0 + self.scale
        dyaw = self.yaw_per_m * distance
        if self.jump_at_m is not None and self.travelled >= self.jump_at_m:
            step[1, 3] += self.jump_m  # sideways, in the sensor frame
            dyaw += self.jump
            self.jump_at_m = None  # once
        # the heading error turns about the world vertical, not the (tilted) sensor z axis: a
        # turn about sensor z would also tilt the drifted frame, more at each step
        turned = self._drifted.copy()
        turned[:3, :3] = planar_pose(0.0, 0.0, dyaw)[:3, :3] @ turned[:3, :3]
        self._true = T.copy()
        self._drifted = turned @ step
        return self._drifted.copy()
