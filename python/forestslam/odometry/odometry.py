"""LiDAR odometry from tree stems (Gupta et al. 2023, Section 3.3) and its baselines: a thin
wrapper over the C++ `forestslam::odometry::TreeOdometry` (deskew -> perception -> tree matching
-> shape-to-shape -> point-to-plane ICP -> local map, with its constant-velocity motion model),
which converts the configs once and the results of every scan.

Methods: "trees" (stems + shape-to-shape + ICP), "icp", "fpfh" (FPFH + RANSAC + ICP baseline),
"stem_centre_lm" (Shao et al.). Fewer than `min_stems` matched stems (or a failed registration):
ICP with the velocity prior and the pose marked degraded; with nothing usable, the prediction
itself. The run never stops on a bad scan.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from forestslam.errors import InputError
from forestslam.io.scan import Scan
from forestslam.odometry.bridge import fill_core
from forestslam.odometry.config import METHODS, MODES, OdometryConfig
from forestslam.perception.pipeline import stems_from_core
from forestslam.sensors import SensorProfile, load_profile

log = logging.getLogger(__name__)


@dataclass
class OdometryStep:
    """The odometry result of one scan.

    stamp: scan stamp (s). T_world_sensor: (4,4) pose of the sensor at the stamp in the world
    frame (the first scan's sensor frame). covariance: (3,3) over x, y, yaw of this scan's
    registration, as a body-frame (current sensor frame) perturbation; usable as the covariance of
    the step from the previous scan. covariance6: (6,6) body-frame (tx,ty,tz,rx,ry,rz) when a
    registration produced the pose, else None. degraded: the pose rests on the velocity prior
    (too few stems, failed or rejected registration). stems: the scan's detected stems (sensor
    frame at the stamp, deskewed). timing: per-stage wall-clock ms; cpu_ms: the same stages in
    process CPU ms. method: what produced the pose. matched_stems: stem pairs used.
    motion_restarted: the motion model restarted before this scan (stamp gap or jump back).
    """

    stamp: float
    T_world_sensor: np.ndarray
    covariance: np.ndarray
    degraded: bool
    stems: Any
    timing: dict[str, float] = field(default_factory=dict)
    covariance6: np.ndarray | None = None
    method: str = ""
    matched_stems: int = 0
    cpu_ms: dict[str, float] = field(default_factory=dict)
    motion_restarted: bool = False


def core_sensor(profile: SensorProfile) -> Any:
    """The C++ OdometrySensor of a sensor profile."""
    from forestslam import _core
    from forestslam.perception.pipeline import sensor_geometry

    sensor = _core.OdometrySensor()
    sensor.geometry = sensor_geometry(profile)
    sensor.kind = profile.kind
    threshold = profile.intensity_threshold
    sensor.intensity_threshold = math.nan if threshold is None else float(threshold)
    return sensor


def core_perception(profile: SensorProfile, config: Any | None) -> Any:
    """The C++ PerceptionConfig of a PerceptionConfig (default: its defaults)."""
    from forestslam.perception.config import PerceptionConfig
    from forestslam.perception.pipeline import core_options

    return core_options(config or PerceptionConfig(), profile)


def core_odometry_config(config: OdometryConfig) -> Any:
    """The C++ OdometryConfig of an OdometryConfig, validated (InputError naming the field)."""
    from forestslam import _core

    for name, value, choices in (("method", config.method, METHODS), ("mode", config.mode, MODES)):
        if value not in choices:
            choice = ", ".join(choices)
            raise InputError(f"odometry {name} {value!r} unknown; choose one of {choice}")
    core = fill_core(config, _core.OdometryConfig(), "odometry")
    try:
        _core.validate_odometry_config(core)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    return core


def _column(values: np.ndarray | None, dtype) -> np.ndarray | None:
    return None if values is None else np.ascontiguousarray(values, dtype=dtype).reshape(-1)


class Odometry:
    """`Odometry(sensor, config=None).step(scan) -> OdometryStep`, one scan at a time in time
    order. sensor: profile name, YAML path or SensorProfile. perception_config: the
    PerceptionConfig of the stem detection (default: its defaults). stem_fits False: the steps'
    stems come without their per-stem fit qualities (`Stems.diameters` empty; DBH and
    centres are there), which saves most of the conversion of the stems into Python."""

    def __init__(
        self,
        sensor: str | SensorProfile,
        config: OdometryConfig | None = None,
        perception_config: Any | None = None,
        stem_fits: bool = True,
    ) -> None:
        from forestslam import _core

        self.sensor = load_profile(sensor)
        self.cfg = config or OdometryConfig()
        self.perception_config = perception_config
        self.stem_fits = stem_fits
        self._odometry = _core.TreeOdometry(
            core_sensor(self.sensor),
            core_odometry_config(self.cfg),
            core_perception(self.sensor, perception_config),
        )
        self.n = 0

    @property
    def motion_model(self) -> Any:
        """The C++ ConstantVelocityModel (twist, pose, time)."""
        return self._odometry.motion_model

    def step(self, scan: Scan) -> OdometryStep:
        """Register one scan; returns its OdometryStep."""
        points = np.ascontiguousarray(scan.points, dtype=np.float64).reshape(-1, 3)
        try:
            res = self._odometry.register_scan(
                float(scan.stamp),
                points,
                _column(scan.intensity, np.float64),
                _column(scan.ring, np.int32),
                _column(scan.time, np.float64),
            )
        except ValueError as exc:
            raise InputError(f"scan at {float(scan.stamp):.3f} s: {exc}") from None
        self._warn(res)
        self.n += 1
        return OdometryStep(
            stamp=float(res.stamp),
            T_world_sensor=np.array(res.T_world_sensor),
            covariance=np.array(res.covariance),
            degraded=bool(res.degraded),
            stems=stems_from_core(res.stems, fits=self.stem_fits),
            timing=dict(res.timing),
            covariance6=None if res.covariance6 is None else np.array(res.covariance6),
            method=res.method,
            matched_stems=int(res.matched_stems),
            cpu_ms=dict(res.cpu_ms),
            motion_restarted=bool(res.stamp_check.restarted),
        )

    def _warn(self, res) -> None:
        check = res.stamp_check
        if check.restarted:
            why = (
                "the stamp does not advance"
                if check.gap_s <= 0
                else f"more than max_stamp_gap_s = {self.cfg.max_stamp_gap_s:g} s"
            )
            log.warning(
                "scan %d at %.3f s: %+.1f s since the previous scan (%s); the motion model "
                "restarts without velocity",
                self.n,
                res.stamp,
                check.gap_s,
                why,
            )
        if res.perception_error:
            log.warning(
                "scan at %.3f s: perception failed (%s); no stems", res.stamp, res.perception_error
            )
