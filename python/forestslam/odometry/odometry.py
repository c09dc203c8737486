"""LiDAR odometry from tree stems (Gupta et al. 2023, Section 3.3) and its baselines.

Per scan: constant-velocity prediction -> deskew (spinning scans with per-point time) ->
perception (stems + ground) -> registration onto the previous scan or a local map of keyframes,
all in the world frame (the first scan's sensor frame), so the registration result is
T_world_sensor itself:

- "trees": stems matched by mutually exclusive nearest neighbours under the prediction, a
  shape-to-shape Gaussian registration over x, y, yaw (with a pair consensus against wrong
  matches) as initial pose, refined by point-to-plane ICP on stem + ground points, 6 DoF;
- "icp": the same ICP from the prediction; "fpfh": FPFH + RANSAC + ICP on the whole scan;
- "stem_centre_lm": stem centres and points by Levenberg-Marquardt (Shao et al.), when built.

Fewer than `min_stems` matched stems (or a failed registration): ICP with the velocity prior and
the pose marked degraded; with nothing usable, the prediction itself. The run never stops.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from forestslam.errors import ForestSlamError, InputError
from forestslam.io.scan import Scan
from forestslam.odometry.config import METHODS, MODES, OdometryConfig
from forestslam.odometry.deskew import deskew_points, se3_exp, se3_log
from forestslam.registration import facade as reg
from forestslam.sensors import SensorProfile, load_profile

log = logging.getLogger(__name__)


@dataclass
class OdometryStep:
    """The odometry result of one scan.

    stamp: scan stamp (s). T_world_sensor: (4,4) pose of the sensor at the stamp in the world
    frame (the first scan's sensor frame). covariance: (3,3) over x, y, yaw of this scan's
    registration, as a body-frame (current sensor frame) perturbation; usable as the covariance of
    the step from the previous scan. covariance6: (6,6) body-frame (tx,ty,tz,rx,ry,rz) when the
    final registration was 6-DoF, else None. degraded: the pose rests on the velocity prior
    (too few stems, failed or rejected registration). stems: the scan's detected stems (sensor
    frame, deskewed). timing: per-stage wall-clock ms; cpu_ms: the same stages in process CPU
    ms (the one-core cost whatever the machine's load). method: what produced the pose.
    matched_stems: stem pairs used.
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


@dataclass
class _Frame:
    """World-frame content of a keyframe (or of the previous scan)."""

    T_world_sensor: np.ndarray
    stem_pos: np.ndarray  # (K,3) breast-height centres (x, y, z)
    stem_cov: np.ndarray  # (K,3,3)
    cloud: np.ndarray  # (N,3) stem + ground points (or the whole scan for "fpfh")


def _planar_block(cov6: np.ndarray) -> np.ndarray:
    idx = [0, 1, 5]
    return cov6[np.ix_(idx, idx)]


def _world_left_to_body_planar(cov3: np.ndarray, T: np.ndarray) -> np.ndarray:
    """x, y, yaw covariance of a world-frame (left) perturbation -> current sensor frame."""
    c, s = T[0, 0], T[1, 0]
    n = math.hypot(c, s) or 1.0
    Rt = np.array([[c, s], [-s, c]]) / n
    A = np.eye(3)
    A[:2, :2] = Rt
    A[:2, 2] = Rt @ np.array([-T[1, 3], T[0, 3]])  # R^T J t
    return A @ cov3 @ A.T


def _world_left_to_body6(cov6: np.ndarray, T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    A = np.zeros((6, 6))
    A[:3, :3] = R.T
    A[:3, 3:] = -R.T @ tx
    A[3:, 3:] = R.T
    return A @ cov6 @ A.T


def transform_stems(stems, T: np.ndarray):
    """The same stems expressed in another frame: p' = T p for every point-like field."""
    from forestslam.perception import Stems

    R = T[:3, :3]
    k = len(stems.xy)
    centre = _transform(T, np.column_stack([stems.xy, stems.z]))
    base = np.column_stack([stems.xy, stems.base_z]) if k else np.zeros((0, 3))
    return Stems(
        xy=centre[:, :2],
        dbh=stems.dbh,
        z=centre[:, 2],
        mean=_transform(T, np.asarray(stems.mean).reshape(-1, 3)),
        cov=R @ np.asarray(stems.cov).reshape(-1, 3, 3) @ R.T,
        axis=np.asarray(stems.axis).reshape(-1, 3) @ R.T,
        points=[_transform(T, np.asarray(p).reshape(-1, 3)) for p in stems.points],
        base_z=_transform(T, base)[:, 2],
        ground=_transform(T, np.asarray(stems.ground).reshape(-1, 3)),
        diameters=list(getattr(stems, "diameters", [])),
        timing=dict(stems.timing),
        counts=dict(getattr(stems, "counts", {})),
        cpu_ms=dict(getattr(stems, "cpu_ms", {})),
    )


def _now() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _yaw(T: np.ndarray) -> float:
    return math.atan2(T[1, 0], T[0, 0])


def _levelled_planar(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split T = P @ L: P rotation about z (plus translation), L roll/pitch only."""
    yaw = _yaw(T)
    P = np.eye(4)
    P[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    P[:3, 3] = T[:3, 3]
    L = np.eye(4)
    L[:3, :3] = P[:3, :3].T @ T[:3, :3]
    return P, L


def _transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(p @ T[:3, :3].T + T[:3, 3])


class Odometry:
    """`Odometry(sensor, config=None).step(scan) -> OdometryStep`, one scan at a time in time
    order. sensor: profile name, YAML path or SensorProfile. perception_config: the
    PerceptionConfig passed to `forestslam.perception.detect` (default: its defaults)."""

    def __init__(
        self,
        sensor: str | SensorProfile,
        config: OdometryConfig | None = None,
        perception_config: Any | None = None,
    ) -> None:
        self.sensor = load_profile(sensor)
        self.cfg = config or OdometryConfig()
        if self.cfg.method not in METHODS:
            raise InputError(
                f"odometry method {self.cfg.method!r} unknown; choose one of {', '.join(METHODS)}"
            )
        if self.cfg.mode not in MODES:
            raise InputError(
                f"odometry mode {self.cfg.mode!r} unknown; choose one of {', '.join(MODES)}"
            )
        from forestslam import _core

        self._core = _core
        if self.cfg.method == "stem_centre_lm" and not hasattr(_core, "register_stem_centre_lm"):
            raise InputError("odometry method 'stem_centre_lm' is not available in this build")
        self.perception_config = perception_config
        self._T: np.ndarray | None = None  # last T_world_sensor
        self._stamp: float | None = None
        self._t_ref: float | None = None  # absolute time of self._T (mid-sweep)
        self._t_mid0 = 0.0
        self._W = np.eye(4)  # output world (first stamp frame) <- state world (first mid-sweep)
        self._twist = np.zeros(6)  # body-frame velocity per second
        self._keyframes: deque[_Frame] = deque(maxlen=max(1, self.cfg.local_map_keyframes))
        self._target: Any = None  # PlaneTarget of the current target cloud
        self._target_cloud = np.zeros((0, 3))
        self._target_stems = (np.zeros((0, 3)), np.zeros((0, 3, 3)))
        self._lm_target: Any = None
        self._cpu: dict[str, float] = {}  # per-stage CPU ms of the current step
        self.n = 0

    # ------------------------------------------------------------------ public
    def step(self, scan: Scan) -> OdometryStep:
        """Register one scan; returns its OdometryStep. Scans must come in time order."""
        timing: dict[str, float] = {}
        self._cpu = {}
        t_start, c_start = time.perf_counter(), time.process_time()
        stamp = float(scan.stamp)
        if self._stamp is not None and not stamp > self._stamp:
            raise InputError(
                f"scan stamp {stamp:.6f} s is not after the previous {self._stamp:.6f} s"
            )
        # Scans are deskewed to, and registered at, the middle of their sweep (t_mid after the
        # stamp): a velocity error then distorts the scan symmetrically and does not feed back
        # into the next pose. The pose at the stamp is extrapolated from it afterwards.
        t_mid = self._mid_time(scan)
        t_ref = stamp + t_mid
        dt = 0.0 if self._t_ref is None else t_ref - self._t_ref
        T_pred = np.eye(4) if self._T is None else self._T @ se3_exp(self._twist * dt)

        tic = _now()
        points = self._deskewed(scan, t_mid)
        self._lap(timing, "deskew", tic)

        tic = _now()
        stems = self._detect(scan, points)
        self._lap(timing, "perception", tic)

        cloud = self._stem_ground_cloud(stems)
        full = None
        if self.cfg.method == "fpfh":
            full = reg.voxel_downsample(points, self.cfg.registration.fpfh.voxel_m)
            full = self._thin(full, self.cfg.fpfh_max_points)
        stem_pos, stem_cov = self._stem_gaussians(stems)

        if self._T is None:
            T, cov6, degraded, method, matched = np.eye(4), np.zeros((6, 6)), False, "first", 0
        else:
            T, cov6, degraded, method, matched = self._register(
                T_pred, cloud, full, points, stems, stem_pos, stem_cov, timing
            )

        tic = _now()
        self._update(stamp, t_ref, T, cloud if full is None else full, stem_pos, stem_cov)
        self._lap(timing, "map", tic)

        # From the mid-sweep frame to the frame at the stamp (T_mid_stamp maps stamp-frame points
        # into the mid-sweep frame); stems move along so that they sit in the output pose's frame.
        T_mid_stamp = se3_exp(-self._twist * t_mid) if t_mid else np.eye(4)
        if self.n == 0:
            self._t_mid0 = t_mid
        elif self.n == 1:
            # The state's world frame is the first scan's mid-sweep frame; now that the velocity
            # is known, outputs are re-anchored to its frame at the stamp.
            self._W = se3_exp(self._twist * self._t_mid0)
        T_out = self._W @ T @ T_mid_stamp
        if t_mid and len(stems.xy):
            stems = transform_stems(stems, np.linalg.inv(T_mid_stamp))
        timing["total"] = (time.perf_counter() - t_start) * 1e3
        timing["cpu_total"] = (time.process_time() - c_start) * 1e3  # process CPU, all threads
        self._cpu["total"] = timing["cpu_total"]

        cov3 = _world_left_to_body_planar(_planar_block(cov6), T_out)
        cov6_body = None if method in ("first", "prediction") else _world_left_to_body6(cov6, T_out)
        self.n += 1
        return OdometryStep(
            stamp=stamp,
            T_world_sensor=T_out,
            covariance=cov3,
            degraded=degraded,
            stems=stems,
            timing=timing,
            covariance6=cov6_body,
            method=method,
            matched_stems=matched,
            cpu_ms=dict(self._cpu),
        )

    # --------------------------------------------------------------- stages
    def _lap(self, timing: dict[str, float], name: str, tic: tuple[float, float]) -> None:
        timing[name] = (time.perf_counter() - tic[0]) * 1e3
        self._cpu[name] = (time.process_time() - tic[1]) * 1e3

    def _deskews(self, scan: Scan) -> bool:
        return bool(
            self.cfg.deskew
            and scan.time is not None
            and self.sensor.kind == "spinning"
            and len(scan.points)
        )

    def _mid_time(self, scan: Scan) -> float:
        if not self._deskews(scan):
            return 0.0
        t = np.asarray(scan.time, dtype=np.float64)
        t = t[np.isfinite(t)]
        return float(0.5 * (t.min() + t.max())) if len(t) else 0.0

    def _deskewed(self, scan: Scan, t_mid: float) -> np.ndarray:
        if self._deskews(scan) and self._T is not None:
            return deskew_points(scan.points, scan.time - t_mid, self._twist)
        return scan.points

    def _detect(self, scan: Scan, points: np.ndarray):
        from forestslam.perception import Stems, detect

        if len(points) == 0:
            return Stems.empty()
        moved = Scan(scan.stamp, points, scan.intensity, scan.ring, scan.time)
        try:
            return detect(moved, self.sensor, self.perception_config)
        except ForestSlamError as exc:
            log.warning("scan %.3f s: perception failed (%s); no stems", scan.stamp, exc)
            return Stems.empty()

    def _thin(self, p: np.ndarray, limit: int) -> np.ndarray:
        if len(p) <= limit:
            return p
        idx = np.linspace(0, len(p) - 1, limit).astype(np.int64)  # deterministic, spread out
        return np.ascontiguousarray(p[idx])

    def _stem_ground_cloud(self, stems) -> np.ndarray:
        parts = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in stems.points]
        parts.append(np.asarray(stems.ground, dtype=np.float64).reshape(-1, 3))
        cloud = np.concatenate(parts) if parts else np.zeros((0, 3))
        cloud = cloud[np.isfinite(cloud).all(axis=1)]
        if len(cloud) == 0:
            return np.zeros((0, 3))
        cloud = reg.voxel_downsample(cloud, self.cfg.source_voxel_m)
        return self._thin(cloud, self.cfg.max_source_points)

    def _stem_gaussians(self, stems) -> tuple[np.ndarray, np.ndarray]:
        """Stem Gaussians for shape-to-shape: breast-height centre (less view-dependent than the
        mean of the visible arc) with the covariance of the stem points."""
        k = len(stems.xy)
        if k == 0:
            return np.zeros((0, 3)), np.zeros((0, 3, 3))
        pos = np.column_stack([np.asarray(stems.xy, float), np.asarray(stems.z, float)])
        cov = np.asarray(stems.cov, dtype=np.float64).reshape(k, 3, 3)
        ok = np.isfinite(pos).all(axis=1) & np.isfinite(cov).reshape(k, 9).all(axis=1)
        return np.ascontiguousarray(pos[ok]), np.ascontiguousarray(cov[ok])

    def _register(self, T_pred, cloud, full, points, stems, stem_pos, stem_cov, timing):
        cfg = self.cfg
        rcfg = cfg.registration
        method = cfg.method
        matched = 0
        T_init = T_pred
        use_prior = False
        result = None
        if method == "fpfh":
            tic = _now()
            if self._target_cloud is not None and len(full) and len(self._target_cloud):
                result = reg.register_fpfh(full, self._target_cloud, T_pred, rcfg.fpfh, rcfg.icp)
            self._lap(timing, "fpfh", tic)
            return self._accept(result, T_pred, False, "fpfh", 0)
        if method == "stem_centre_lm":
            return self._register_lm(T_pred, points, stems, timing)
        if method == "trees":
            tic = _now()
            target_pos, target_cov = self._target_stems
            P, L = _levelled_planar(T_pred)
            # Stems levelled by the predicted roll/pitch, so that their XY compare with the map.
            src_level = _transform(L, stem_pos) if len(stem_pos) else stem_pos
            pairs = (
                reg.match_trees(src_level, target_pos, P, rcfg.trees)
                if len(stem_pos) and len(target_pos)
                else np.zeros((0, 2), dtype=np.int64)
            )
            self._lap(timing, "match", tic)
            matched = len(pairs)
            if matched >= cfg.min_stems:
                tic = _now()
                Rl = L[:3, :3]
                cov_level = Rl @ stem_cov @ Rl.T
                shape = reg.register_shapes(
                    src_level, cov_level, target_pos, target_cov, pairs, P, rcfg.shape
                )
                self._lap(timing, "shape", tic)
                if shape.inliers >= cfg.min_stems:
                    S = np.asarray(shape.T_target_source)
                    T_init = S @ L
                    T_init[2, 3] = T_pred[2, 3]
                    matched = shape.inliers
                else:
                    use_prior = True
            else:
                use_prior = True
        tic = _now()
        if self._target is not None and len(cloud):
            info = None
            if use_prior:
                sm, sr = cfg.prior_sigma_m, math.radians(cfg.prior_sigma_deg)
                info = np.diag([1 / sm**2] * 3 + [1 / sr**2] * 3)
            result = reg.icp_point_to_plane(
                self._target, cloud, T_init, rcfg.icp, info, T_pred if use_prior else None
            )
        self._lap(timing, "icp", tic)
        name = method if not use_prior else "icp_prior"
        degraded = use_prior and method == "trees"
        return self._accept(result, T_pred, degraded, name, matched)

    def _register_lm(self, T_pred, points, stems, timing):
        """Stem-centre LM: stem centres (with radius) and thinned points as features."""
        tic = _now()
        result = None
        if self._lm_target is not None:
            ok = np.isfinite(stems.dbh)
            centres = np.column_stack([stems.xy, stems.z])[ok]
            radii = 0.5 * np.asarray(stems.dbh)[ok]
            if hasattr(self._core, "detect_dog_keypoints"):
                real = np.asarray(self._core.detect_dog_keypoints(points)[0]).reshape(-1, 3)
            else:
                real = self._thin(reg.voxel_downsample(points, 0.5), 400)
            out = self._core.register_stem_centre_lm(
                self._lm_target,
                np.ascontiguousarray(centres, dtype=np.float64),
                np.ascontiguousarray(radii, dtype=np.float64),
                np.ascontiguousarray(real, dtype=np.float64),
                T_pred,
            )
            result = SimpleNamespace(**out)
        self._lap(timing, "stem_centre_lm", tic)
        return self._accept(result, T_pred, False, "stem_centre_lm", 0)

    def _accept(self, result, T_pred, degraded, name, matched):
        """Keep a registration unless it failed or jumped away from the prediction."""
        cfg = self.cfg
        big = np.diag([cfg.prior_sigma_m**2] * 3 + [math.radians(cfg.prior_sigma_deg) ** 2] * 3)
        if result is None or result.inliers == 0:
            return T_pred, big, True, "prediction", matched
        T = np.asarray(result.T_target_source, dtype=np.float64)
        d = np.linalg.inv(T_pred) @ T
        shift = float(np.linalg.norm(d[:3, 3]))
        turn = math.degrees(abs(float(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))))
        if (
            not np.isfinite(T).all()
            or shift > cfg.max_correction_m
            or turn > cfg.max_correction_deg
        ):
            log.debug("registration rejected: %.2f m / %.1f deg from the prediction", shift, turn)
            return T_pred, big, True, "prediction", matched
        cov6 = np.asarray(result.covariance, dtype=np.float64)
        degraded = (
            degraded
            or bool(result.degenerate and name != "fpfh")
            or not (result.converged or result.iterations > 0)
        )
        if result.degenerate:
            cov6 = cov6 + big  # the prior carried the unobserved directions
        return T, cov6, degraded, name, matched

    # ---------------------------------------------------------------- state
    def _update(self, stamp, t_ref, T, cloud, stem_pos, stem_cov) -> None:
        cfg = self.cfg
        if self._T is not None and self._t_ref is not None:
            dt = t_ref - self._t_ref
            if dt > 0:
                twist = se3_log(np.linalg.inv(self._T) @ T) / dt
                # A platform cannot outrun these: a wrong registration must not make the
                # velocity prior run away with the following scans.
                v, w = np.linalg.norm(twist[:3]), np.linalg.norm(twist[3:])
                if v > cfg.max_speed_mps:
                    twist[:3] *= cfg.max_speed_mps / v
                if w > math.radians(cfg.max_turn_rate_dps):
                    twist[3:] *= math.radians(cfg.max_turn_rate_dps) / w
                self._twist = twist
        self._T, self._stamp, self._t_ref = T, stamp, t_ref
        R = T[:3, :3]
        frame = _Frame(
            T,
            _transform(T, stem_pos) if len(stem_pos) else np.zeros((0, 3)),
            R @ stem_cov @ R.T if len(stem_cov) else np.zeros((0, 3, 3)),
            _transform(T, cloud) if len(cloud) else np.zeros((0, 3)),
        )
        if cfg.mode == "scan_to_scan":
            self._set_target([frame])
            return
        if self._keyframes:
            last = self._keyframes[-1].T_world_sensor
            rel = np.linalg.inv(last) @ T
            far = np.linalg.norm(rel[:3, 3]) >= cfg.keyframe_distance_m
            turned = abs(math.degrees(_yaw(rel))) >= cfg.keyframe_yaw_deg
            if not (far or turned):
                return
        self._keyframes.append(frame)
        self._set_target(list(self._keyframes))

    def _set_target(self, frames: list[_Frame]) -> None:
        cfg = self.cfg
        centre = frames[-1].T_world_sensor[:3, 3]
        # Stems: newest first; an older stem within stem_merge_m of a kept one is the same tree.
        pos, cov = np.zeros((0, 3)), np.zeros((0, 3, 3))
        for f in reversed(frames):
            if not len(f.stem_pos):
                continue
            if len(pos):
                d = np.linalg.norm(f.stem_pos[:, None, :2] - pos[None, :, :2], axis=2)
                new = d.min(axis=1) > cfg.stem_merge_m
            else:
                new = np.ones(len(f.stem_pos), dtype=bool)
            pos = np.concatenate([pos, f.stem_pos[new]])
            cov = np.concatenate([cov, f.stem_cov[new]])
        self._target_stems = (np.ascontiguousarray(pos), np.ascontiguousarray(cov))
        clouds = [f.cloud for f in frames if len(f.cloud)]
        if not clouds:
            self._target, self._target_cloud, self._lm_target = None, np.zeros((0, 3)), None
            return
        cloud = np.concatenate(clouds)
        near = np.linalg.norm(cloud[:, :2] - centre[:2], axis=1) <= cfg.local_map_radius_m
        cloud = cloud[near]
        if len(frames) > 1:
            voxel = cfg.registration.fpfh.voxel_m if cfg.method == "fpfh" else cfg.map_voxel_m
            cloud = reg.voxel_downsample(cloud, voxel)
        self._target_cloud = np.ascontiguousarray(cloud)
        if cfg.method == "fpfh":
            return
        if cfg.method == "stem_centre_lm":
            self._lm_target = self._core.StemCentreTarget(self._target_cloud)
            return
        self._target = reg.PlaneTarget(self._target_cloud, cfg.registration.icp.normal_k)
