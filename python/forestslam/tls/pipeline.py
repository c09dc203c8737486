"""MLS-to-TLS plot mapping (Shao et al. 2020): each MLS frame gets an initial pose from a
constant-velocity prediction off the last trusted pose, then the stem-centre LM (virtual + DoG
features) against a local target: a voxelized copy of the global map (TLS reference + accepted
MLS frames) cropped around the predicted pose. When the LM from the prediction is not trusted
(not converged, degenerate, high residuals, or a correction too large for the motion model),
3D-NDT against the last trusted frame chained onto its pose (the paper's Section 3.3) gives a
second initial pose. Frames that still fail are rejected: not merged, not chained from.
The velocity (deskew, prediction) is used only while fresh (RegistrationConfig
.max_velocity_age_s). A trusted frame of a spinning scanner is registered again with its motion
during the sweep (continuous time, see tls.sweep) and its points are moved with it.

What joins the map: a trusted frame whose in-sweep motion was estimated (when it has per-point
times), whose stems sit on the reference's stems, that was not itself relocalized, and whose
pose holds on the TLS reference alone (MapConfig.accept_reference_*). Frames that do not join
still get a pose (tracking goes on through them).

The first frame's pose in the TLS frame comes from `initial_pose` when given, else from a
coarse stem alignment: stem positions of the frame (ring circle fits) are matched to those of
the reference by pairwise spacing voting (x, y, yaw), the height from the local ground of both
clouds; the LM then refines all 6 DoF. This needs the walk to start where the frame sees at
least `coarse_min_stems` stems that the TLS also sees (e.g. inside the plot); frames before the
first alignable one (up to `coarse_max_frames`) are skipped.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from forestslam.errors import InputError, ProcessingError
from forestslam.io import Scan
from forestslam.odometry.deskew import deskew_points, se3_exp, se3_log
from forestslam.tls.config import TlsConfig
from forestslam.tls.features import (
    FrameFeatures,
    coarse_stem_alignment,
    frame_features,
    ground_height_near,
    planar_pose,
    reference_stems,
)
from forestslam.tls.sweep import apply_sweep, feature_times, sweep_pose

log = logging.getLogger(__name__)


def _core():
    from forestslam import _core

    return _core


@dataclass
class FrameRecord:
    stamp: float
    T_tls_sensor: np.ndarray
    accepted: bool
    converged: bool
    degenerate: bool
    virtual_inliers: int
    virtual_rms_m: float
    real_inliers: int
    real_rms_m: float
    ms_features: float
    ms_lm: float
    ms_ndt: float
    ms_target: float = 0.0  # local LM target (re-)build charged to this frame
    fallback: bool = False  # the second initial pose was used (NDT, or velocity in NDT mode)
    # Registration frame: the sensor at t_mid_s after the stamp (mid-sweep); the scan was
    # deskewed with deskew_twist (6,) per second (zeros: not deskewed), see odometry.deskew.
    t_mid_s: float = 0.0
    deskew_twist: np.ndarray = field(default_factory=lambda: np.zeros(6))
    T_tls_mid: np.ndarray = field(default_factory=lambda: np.eye(4))  # pose at t_mid_s
    relocalized: bool = False  # placed afresh by its stems on the reference's (tracking lost)
    # The acceptance test against the reference alone (NaN when not run): how far the LM on
    # the reference moved the frame's pose.
    reference_correction_m: float = float("nan")
    reference_correction_deg: float = float("nan")
    # In-sweep motion (K,6) estimated by the LM (see tls.sweep.apply_sweep; empty: rigid),
    # applied to the points (deskewed to t_mid_s) after deskew_twist.
    sweep: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))


@dataclass
class TlsRun:
    """Result: per-frame records (poses T_tls_sensor), the merged map (M,3) in the TLS frame,
    the reference (R,3), registered stem centres of accepted frames (list of (V,3))."""

    frames: list[FrameRecord]
    map_points: np.ndarray
    reference: np.ndarray
    frame_centres: list[np.ndarray] = field(default_factory=list)
    initial_method: str = ""

    @property
    def stamps(self) -> np.ndarray:
        return np.array([f.stamp for f in self.frames])

    @property
    def poses(self) -> np.ndarray:
        return np.array([f.T_tls_sensor for f in self.frames]).reshape(-1, 4, 4)


def _check_reference(reference: np.ndarray) -> np.ndarray:
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    ref = ref[np.isfinite(ref).all(axis=1)]
    if len(ref) < 1000:
        raise InputError(
            f"the TLS reference has {len(ref)} valid points; a plot scan needs many more"
        )
    return np.ascontiguousarray(ref)


def _frame_points(scan: Scan, config: TlsConfig) -> tuple[np.ndarray, np.ndarray | None]:
    """Usable points (N,3) of a scan (finite, within the frame's range limits) and their rings."""
    pts, rings, _ = _frame_points_times(scan, config)
    return pts, rings


def _frame_points_times(
    scan: Scan, config: TlsConfig
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Usable points (N,3), rings (N,) or None and per-point times (N,) or None (only when the
    scan has finite times and deskewing is enabled)."""
    pts = np.asarray(scan.points, dtype=np.float64)
    rng = np.linalg.norm(pts, axis=1)
    ok = (
        np.isfinite(pts).all(axis=1)
        & (rng >= config.map.frame_min_range_m)
        & (rng <= config.map.frame_max_range_m)
    )
    times = None
    if config.registration.deskew and scan.time is not None and len(scan.time) == len(pts):
        t = np.asarray(scan.time, dtype=np.float64)
        ok &= np.isfinite(t)
        times = t[ok]
    rings = None if scan.ring is None else np.asarray(scan.ring)[ok]
    return np.ascontiguousarray(pts[ok]), rings, times


def registered_points(scan: Scan, record: FrameRecord, config: TlsConfig) -> np.ndarray:
    """The usable points (N,3) of a registered frame in its registration frame (the sensor at
    record.t_mid_s), as the pipeline merged them: deskewed with record.deskew_twist and moved
    by its in-sweep motion record.sweep. Place them with record.T_tls_mid."""
    pts, _, times = _frame_points_times(scan, config)
    if times is None:
        return pts
    tau = times - record.t_mid_s
    if np.any(record.deskew_twist):
        pts = deskew_points(pts, tau, record.deskew_twist)
    if len(record.sweep):
        pts = apply_sweep(pts, tau, record.T_tls_mid, record.sweep)
    return pts


class _GlobalMap:
    """TLS reference + accepted frames, voxelized (merged in batches), and the local LM
    target: a coarser voxel copy of the map cropped around the predicted frame (x-y disc,
    height band of the frame), rebuilt only when the frame leaves the crop or the map grew."""

    def __init__(self, reference: np.ndarray, config: TlsConfig):
        self.core = _core()
        self.config = config
        m = config.map
        self.points = self.core.voxel_downsample(reference, m.voxel_m)
        self.coarse = self._coarse(self.points)
        self.pending: list[np.ndarray] = []
        self.target = None
        self.target_centre = np.zeros(2)
        self.target_z = (0.0, 0.0)
        self.dirty = True

    def _coarse(self, points: np.ndarray) -> np.ndarray:
        m = self.config.map
        if m.target_voxel_m > m.voxel_m:
            return self.core.voxel_downsample(np.ascontiguousarray(points), m.target_voxel_m)
        return points

    def add(self, points_tls: np.ndarray) -> None:
        self.pending.append(self.core.voxel_downsample(points_tls, self.config.map.voxel_m))
        if len(self.pending) >= self.config.map.rebuild_every_frames:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        new = np.concatenate(self.pending)
        self.pending.clear()
        self.points = self.core.voxel_downsample(
            np.concatenate([self.points, new]), self.config.map.voxel_m
        )
        if len(self.points) > self.config.map.max_points:
            raise ProcessingError(
                f"the merged map exceeds {self.config.map.max_points} points; "
                "raise map.voxel_m or map.max_points"
            )
        self.coarse = self._coarse(np.concatenate([self.coarse, self._coarse(new)]))
        self.dirty = True

    def target_at(self, xy: np.ndarray, z_range: tuple[float, float]):
        """LM target around xy (2,) covering heights z_range (the frame's, in the TLS frame),
        re-cropped only when needed. -> (target, rebuilt)."""
        m = self.config.map
        xy = np.asarray(xy, dtype=np.float64)
        if (
            self.target is not None
            and not self.dirty
            and np.linalg.norm(xy - self.target_centre) <= m.target_recrop_m
            and self.target_z[0] <= z_range[0]
            and z_range[1] <= self.target_z[1]
        ):
            return self.target, False
        zlo, zhi = z_range[0] - m.target_z_margin_m, z_range[1] + m.target_z_margin_m
        c = self.coarse
        keep = (c[:, 2] >= zlo) & (c[:, 2] <= zhi)
        keep &= np.sum((c[:, :2] - xy) ** 2, axis=1) <= m.target_radius_m**2
        self.target = self.core.StemCentreTarget(np.ascontiguousarray(c[keep]))
        self.target_centre = xy
        self.target_z = (zlo, zhi)
        self.dirty = False
        return self.target, True


def _z_range(points: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """Height range of the frame's points (N,3) moved by T (4,4)."""
    z = points @ T[2, :3] + T[2, 3]
    return float(z.min()), float(z.max())


def _correction(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between two poses."""
    d = np.linalg.inv(T_a) @ T_b
    c = np.clip((np.trace(d[:3, :3]) - 1) / 2, -1.0, 1.0)
    return float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3])), float(np.degrees(np.arccos(c)))


def _trusted(lm: dict, T_pred: np.ndarray | None, config: TlsConfig) -> bool:
    reg = config.registration
    if not lm["converged"] or lm["degenerate"]:
        return False
    if lm["real_inliers"] > 0 and lm["real_rms_m"] > reg.good_real_rms_m:
        return False
    if T_pred is not None:
        dt, dr = _correction(T_pred, lm["T_target_source"])
        if dt > reg.max_correction_m or dr > reg.max_correction_deg:
            return False
    return True


def _lm(core, target, feats, T_init, config: TlsConfig, **options) -> dict:
    reg = config.registration
    options = {
        "max_rounds": reg.lm_max_rounds,
        "converged_translation_m": reg.lm_converged_translation_m,
        "converged_rotation_rad": reg.lm_converged_rotation_rad,
        **options,
    }
    return core.register_stem_centre_lm(
        target,
        feats.centres,
        feats.radii,
        feats.real_points,
        np.ascontiguousarray(T_init),
        virtual_gate_m=reg.lm_virtual_gate_m,
        plane_gate_m=reg.lm_plane_gate_m,
        robust_scale_m=reg.lm_robust_scale_m,
        **options,
    )


class _ReferenceCheck:
    """The acceptance test against the TLS reference alone (see MapConfig.accept_reference_*):
    a KD-tree over the voxelized reference, built on first use; the frame's LM from its pose
    with the fine gates only (no coarse start) and a few rounds."""

    def __init__(self, reference: np.ndarray, config: TlsConfig):
        self.reference = reference
        self.config = config
        self.target = None

    def __call__(self, feats, T: np.ndarray) -> tuple[bool, dict]:
        core = _core()
        if self.target is None:
            voxel = max(self.config.map.target_voxel_m, self.config.map.voxel_m)
            self.target = core.StemCentreTarget(core.voxel_downsample(self.reference, voxel))
        m = self.config.map
        r = _lm(
            core,
            self.target,
            feats,
            T,
            self.config,
            max_rounds=m.accept_reference_rounds,
            coarse_gate_factor=1.0,
        )
        dt, dr = _correction(T, r["T_target_source"])
        r["correction_m"], r["correction_deg"] = dt, dr
        ok = (
            bool(r["converged"])
            and not r["degenerate"]
            and dt <= m.accept_reference_max_m
            and dr <= m.accept_reference_max_deg
        )
        return ok, r


def _sweep_lm(lm: dict, feats, points, times, t_mid: float, lm_at, config: TlsConfig, ms: dict):
    """The trusted rigid result lm refined with the motion during the sweep (see tls.sweep)
    -> (LM result, features moved by that motion into the registration frame, sweep (K,6)),
    or None when the refined LM is not trusted (then the rigid result stands)."""
    reg = config.registration
    t0 = time.process_time()
    real = feats.real_points
    tau_c = feature_times(feats.centres, points, times) - t_mid
    tau_r = feature_times(real, points, times) - t_mid
    ms["features"] += (time.process_time() - t0) * 1e3
    T0 = np.asarray(lm["T_target_source"])
    result = lm_at(
        T0,
        sweep_order=reg.sweep_order,
        centre_times=np.ascontiguousarray(tau_c),
        real_times=np.ascontiguousarray(tau_r),
        max_rounds=reg.sweep_lm_rounds,
        coarse_gate_factor=1.0,
    )
    if not _trusted(result, T0, config):
        return None
    T, sweep = np.asarray(result["T_target_source"]), np.asarray(result["sweep"])
    real = apply_sweep(real, tau_r, T, sweep)
    k = len(feats.keypoints)
    moved = FrameFeatures(
        centres=apply_sweep(feats.centres, tau_c, T, sweep),
        radii=feats.radii,
        stems=feats.stems,
        stem_radii=feats.stem_radii,
        keypoints=real[:k],
        ground=real[k:],
    )
    return result, moved, sweep


def _coarse_initial_pose(
    feats, points: np.ndarray, ref: np.ndarray, ref_stems, config: TlsConfig
) -> np.ndarray | None:
    ref_xyz, ref_r = ref_stems
    found = coarse_stem_alignment(
        feats.stems[:, :2], feats.stem_radii, ref_xyz[:, :2], ref_r, config.registration
    )
    if found is None:
        return None
    (x, y, yaw), n_in = found
    T = planar_pose(x, y, yaw)
    g_frame = ground_height_near(points, np.zeros(2))
    g_ref = ground_height_near(ref, np.array([x, y]))
    if g_frame is not None and g_ref is not None:
        T[2, 3] = g_ref - g_frame
    log.info(
        "coarse stem alignment: %d stems agree, x=%.2f y=%.2f yaw=%.1f deg",
        n_in,
        x,
        y,
        np.degrees(yaw),
    )
    return T


def _stems_on_reference(feats, T: np.ndarray, ref_stems, config: TlsConfig) -> bool:
    """Most frame stems, moved by T, lie on a reference stem of similar radius."""
    ref_xyz, ref_r = ref_stems
    if len(feats.stems) == 0 or len(ref_xyz) == 0:
        return False
    xy = feats.stems[:, :2] @ T[:2, :2].T + T[:2, 3]
    d = np.linalg.norm(xy[:, None, :] - ref_xyz[None, :, :2], axis=2)
    j = np.argmin(d, axis=1)
    hit = (d[np.arange(len(xy)), j] < 0.1) & (np.abs(feats.stem_radii - ref_r[j]) < 0.05)
    need = max(config.registration.coarse_min_stems, int(np.ceil(0.5 * len(xy))))
    return int(hit.sum()) >= need


def register_mls_to_tls(
    scans: Iterable[Scan],
    reference: np.ndarray,
    config: TlsConfig | None = None,
    initial_pose: np.ndarray | None = None,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> TlsRun:
    """Register MLS scans (sensor frame, ring when available) onto a TLS reference (R,3).
    initial_pose (4,4) T_tls_sensor of the first frame, or None for the coarse stem alignment.
    Raises InputError for an unusable reference or no frames, ProcessingError when the first
    frames cannot be placed in the reference (mismatched data)."""
    config = config or TlsConfig()
    core = _core()
    ref = _check_reference(reference)
    gmap = _GlobalMap(ref, config)
    check_reference = _ReferenceCheck(ref, config)
    ref_stems = None
    frames: list[FrameRecord] = []
    centres: list[np.ndarray] = []
    # Previous frame (pose and points, trusted or not), whether it was trusted, and the
    # per-frame velocity from the last pair of consecutive trusted frames.
    T_good = None  # set once the first frame is anchored
    lost = 0  # consecutive frames that did not join the map
    t_good = 0.0
    T_prev = None
    prev_points = None
    prev_good = False
    # Velocity: body-frame twist (6,) per second (translation, rotation vector) between the
    # mid-sweep frames of the last two consecutive frames; t_prev the previous mid-sweep time.
    twist = np.zeros(6)
    t_twist = None  # mid-sweep time of the frame that gave the twist
    t_prev = None
    seen = 0
    method = "given" if initial_pose is not None else "stems"
    for index, scan in enumerate(scans):
        if index % max(1, config.frame_step):
            continue
        seen += 1
        points, rings, times = _frame_points_times(scan, config)
        if len(points) < 100:
            log.warning(
                "frame %d at %.3f has %d usable points: skipped", index, scan.stamp, len(points)
            )
            continue
        # Spinning scans are deskewed to, and registered at, the middle of their sweep: a
        # velocity error then distorts the frame symmetrically; the pose at the stamp is
        # extrapolated from it afterwards.
        t_mid = 0.0 if times is None else float(0.5 * (times.min() + times.max()))
        t_ref = float(scan.stamp) + t_mid
        dt = 0.0 if t_prev is None else max(t_ref - t_prev, 1e-6)
        if t_twist is None or t_ref - t_twist > config.registration.max_velocity_age_s:
            twist = np.zeros(6)  # stale: no deskew, no extrapolation over a long gap
        t0 = time.process_time()
        if times is not None and t_prev is not None and np.any(twist):
            points = deskew_points(points, times - t_mid, twist)
        feats = frame_features(points, rings, config.features)
        ms = {"features": (time.process_time() - t0) * 1e3, "ndt": 0.0, "target": 0.0, "lm": 0.0}

        def lm_at(T_start: np.ndarray, points=points, feats=feats, ms=ms, **options) -> dict:
            """LM of this frame from T_start against the map target cropped around it."""
            t0 = time.process_time()
            target, _ = gmap.target_at(T_start[:2, 3], _z_range(points, T_start))
            t1 = time.process_time()
            result = _lm(core, target, feats, T_start, config, **options)
            ms["target"] += (t1 - t0) * 1e3
            ms["lm"] += (time.process_time() - t1) * 1e3
            return result

        def ndt_from_previous(
            V: np.ndarray, points=points, ms=ms, prev_points=prev_points, T_prev=T_prev
        ) -> np.ndarray | None:
            """T_world_sensor by NDT against the previous frame chained onto its pose, or None."""
            t0 = time.process_time()
            ndt = core.register_ndt(
                prev_points,
                points,
                np.ascontiguousarray(V),
                voxel_m=config.registration.ndt_voxel_m,
                resolution_m=config.registration.ndt_resolution_m,
            )
            ms["ndt"] = (time.process_time() - t0) * 1e3
            return T_prev @ ndt["T_target_source"] if ndt["converged"] else None

        T_pred = None
        if T_good is None:
            if initial_pose is not None:
                T_init = np.asarray(initial_pose, dtype=np.float64)
            else:
                if ref_stems is None:
                    ref_stems = reference_stems(ref, config.features)
                    log.info("reference: %d stems", len(ref_stems[0]))
                T_init = _coarse_initial_pose(feats, points, ref, ref_stems, config)
                if T_init is None:
                    if seen >= config.registration.coarse_max_frames:
                        raise ProcessingError(
                            f"the first {seen} MLS frames cannot be aligned to the reference by "
                            "stem positions (do they show the same plot?); give --initial-pose"
                        )
                    continue
        else:
            V = se3_exp(twist * dt)
            T_pred = T_prev @ V
            T_init = T_pred
            if config.registration.initial_pose == "ndt":
                T_ndt = ndt_from_previous(V)
                if T_ndt is not None:
                    T_pred = T_init = T_ndt

        lm = lm_at(T_init)
        good = _trusted(lm, T_pred, config)
        fallback = relocalized = False
        if not good and T_good is not None and config.registration.initial_pose != "ndt":
            # Fallback: NDT against the previous frame, chained onto its pose.
            T_ndt = ndt_from_previous(V)
            if T_ndt is not None:
                T_init = T_ndt
                lm2 = lm_at(T_ndt)
                if _trusted(lm2, T_ndt, config):
                    lm, good, fallback = lm2, True, True
        elif not good and T_good is not None:
            # Fallback of the NDT mode (NDT can fail at sharp turns): the constant-velocity
            # prediction from the last trusted pose.
            T_vel = T_good @ se3_exp(twist * max(t_ref - t_good, 0.0))
            lm2 = lm_at(T_vel)
            if _trusted(lm2, T_vel, config):
                lm, good, fallback = lm2, True, True
        if T_good is not None and lost >= config.registration.relocalize_after_frames:
            # Tracking lost (the last frames did not join the map: untrusted, or trusted but
            # their stems off the reference's): place the frame afresh by its stems on the
            # reference's stems; kept when trusted and its stems sit on the reference's.
            if ref_stems is None:
                ref_stems = reference_stems(ref, config.features)
            T_c = _coarse_initial_pose(feats, points, ref, ref_stems, config)
            if T_c is not None:
                lm2 = lm_at(T_c)
                if _trusted(lm2, None, config) and _stems_on_reference(
                    feats, lm2["T_target_source"], ref_stems, config
                ):
                    lm, good, fallback, relocalized = lm2, True, True, True
                    log.info("frame %d at %.3f: relocalized on the reference stems", index, t_ref)
        # Motion during the sweep: the trusted frame registered again with it (continuous time).
        sweep = np.zeros((0, 6))
        if good and times is not None and config.registration.sweep_order > 0:
            refined = _sweep_lm(lm, feats, points, times, t_mid, lm_at, config, ms)
            if refined is not None:
                lm, feats, sweep = refined
                points = apply_sweep(points, times - t_mid, lm["T_target_source"], sweep)
        # The pose: the LM's when trusted (in "ndt" mode, whenever it converged, as the
        # paper); else the initial pose. Only trusted frames join the map.
        lm_ok = lm["converged"] and not lm["degenerate"]
        use_lm = good or (config.registration.initial_pose == "ndt" and lm_ok)
        T = lm["T_target_source"] if use_lm else T_init
        stems_agree = (
            lm["virtual_inliers"] >= config.map.accept_min_virtual_inliers
            and lm["virtual_rms_m"] <= config.map.accept_virtual_rms_m
        )
        if T_good is None and good and initial_pose is None:
            stems_agree = stems_agree and _stems_on_reference(feats, T, ref_stems, config)
        # The first frame anchors everything: its stems must sit on the reference's stems.
        if T_good is None and not (good and (stems_agree or initial_pose is not None)):
            if initial_pose is not None or seen >= config.registration.coarse_max_frames:
                raise ProcessingError(
                    "the first MLS frame does not register onto the reference "
                    f"({lm['inliers']} feature pairs): mismatched data or a wrong initial pose"
                )
            continue
        # Only frames whose stems sit on the reference's stems join the map: a frame that
        # registered onto earlier wrongly placed frames must not spread the error.
        if ref_stems is None:
            ref_stems = reference_stems(ref, config.features)
        on_reference = good and stems_agree and _stems_on_reference(feats, T, ref_stems, config)
        # A relocalized frame restarts the tracking but does not join the map itself (a coarse
        # placement can sit in a wrong minimum and still look trusted); a frame joins only when
        # its pose also holds on the TLS reference alone (see MapConfig.accept_reference_*).
        # With per-point times, only a frame whose in-sweep motion was estimated joins: a rigid
        # frame of a vibrating scanner is distorted by centimetres (its ground above all).
        swept = len(sweep) > 0 or times is None or config.registration.sweep_order <= 0
        accepted = False
        ref_dt = ref_dr = float("nan")
        if on_reference and swept and not relocalized:
            t0 = time.process_time()
            accepted, check = check_reference(feats, T)
            ms["lm"] += (time.process_time() - t0) * 1e3
            ref_dt, ref_dr = check["correction_m"], check["correction_deg"]
        lost = 0 if on_reference else lost + 1
        if accepted:
            pts_tls = points @ T[:3, :3].T + T[:3, 3]
            gmap.add(pts_tls)
            centres.append(feats.centres @ T[:3, :3].T + T[:3, 3])
        twist_used = twist.copy()
        # The velocity (NDT guess, prediction and deskew) only from two consecutive trusted
        # poses: a bad pose would distort the next frames through the deskew.
        if T_prev is not None and good and prev_good:
            twist = se3_log(np.linalg.inv(T_prev) @ T) / dt
            t_twist = t_ref
        # The pose at the stamp (sweep start): from the frame's own in-sweep motion when
        # estimated (on top of the deskew it was estimated after), else extrapolated.
        if len(sweep):
            T_stamp = sweep_pose(T, sweep, -t_mid) @ se3_exp(-twist_used * t_mid)
        else:
            T_stamp = T @ se3_exp(-twist * t_mid)
        record = FrameRecord(
            stamp=float(scan.stamp),
            T_tls_sensor=np.asarray(T_stamp),
            accepted=bool(accepted),
            converged=bool(lm["converged"]),
            degenerate=bool(lm["degenerate"]),
            virtual_inliers=int(lm["virtual_inliers"]),
            virtual_rms_m=float(lm["virtual_rms_m"]),
            real_inliers=int(lm["real_inliers"]),
            real_rms_m=float(lm["real_rms_m"]),
            ms_features=ms["features"],
            ms_lm=ms["lm"],
            ms_ndt=ms["ndt"],
            ms_target=ms["target"],
            fallback=fallback,
            t_mid_s=t_mid,
            deskew_twist=twist_used if times is not None else np.zeros(6),
            T_tls_mid=np.asarray(T),
            relocalized=relocalized,
            reference_correction_m=ref_dt,
            reference_correction_deg=ref_dr,
            sweep=sweep,
        )
        frames.append(record)
        if on_frame is not None:
            on_frame(record)
        if good:
            T_good, t_good = T, t_ref
        T_prev, prev_points, prev_good, t_prev = T, points, good, t_ref
    if seen == 0:
        raise InputError("the MLS input holds no scans")
    if not frames:
        raise ProcessingError("no MLS frame could be registered onto the reference")
    gmap.flush()
    return TlsRun(
        frames=frames,
        map_points=gmap.points,
        reference=ref,
        frame_centres=centres,
        initial_method=method,
    )
