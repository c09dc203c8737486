"""MLS-to-TLS plot mapping (Shao et al. 2020): each MLS frame gets an initial pose from a
constant-velocity prediction off the last trusted pose (the odometry's motion model,
forestslam::odometry::ConstantVelocityModel, which also deskews it), then the stem-centre LM
(virtual + DoG features) against a local target: a voxelized copy of the global map (TLS
reference + accepted MLS frames) cropped around the predicted pose. When the LM from the
prediction is not trusted (not converged, degenerate, high residuals, or a correction too large
for the motion model), 3D-NDT against the last trusted frame chained onto its pose (the paper's
Section 3.3) gives a second initial pose. Frames that still fail are rejected: not merged, not
chained from. The velocity (deskew, prediction) is used only while fresh (RegistrationConfig
.max_velocity_age_s: the motion model's max_gap_s). register_mls_to_tls feeds the frames to
_Walk, whose add() reads as the stages of one frame. A trusted frame of a spinning scanner is
registered again with its motion during the sweep (continuous time, see tls.sweep) and its
points are moved with it; so is, with RegistrationConfig.rescue_in_sweep, a frame whose rigid
LM ran out of rounds near its minimum (_rescue_in_sweep: a sweep distorted by motion the deskew
did not know), trusted only if that converges.

What joins the map: a trusted frame whose in-sweep motion was estimated (when it has per-point
times), whose stems sit on the reference's stems, that was not itself relocalized, and whose
pose holds on the TLS reference alone (MapConfig.accept_reference_*). Frames that do not join
still get a pose (tracking goes on through them).

The walk's pose in the TLS frame comes from `initial_pose` (the first frame's) when given, else
from tls.initialize: the first frames are chained by NDT (corrected on their stems) into a
local stem map, placement hypotheses come from stem constellations (triangle-star localizer
and pairwise-spacing vote), each verified by the LM and by stem consensus; frames are tried
until one is placed, and the frames before it are chained back from it (never merged). Every
frame that does not join the map carries its reason (FrameRecord.reason, unmerged_csv).
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from forestslam.errors import InputError, ProcessingError
from forestslam.geometry import planar_pose, transform_points, transform_xy
from forestslam.io import Scan
from forestslam.mapping.voxel import key_step, voxel_keys, x_slab
from forestslam.odometry.deskew import deskew_points, se3_exp, se3_log
from forestslam.tls.bridge import lm_config, motion_model_config, ndt_config
from forestslam.tls.bridging import bridge_unmerged
from forestslam.tls.config import TlsConfig
from forestslam.tls.features import (
    FrameFeatures,
    coarse_stem_alignment,
    frame_features,
    ground_height_near,
    reference_stems,
)
from forestslam.tls.initialize import Initializer, PendingFrame
from forestslam.tls.sweep import apply_sweep, feature_times, sweep_pose

if TYPE_CHECKING:
    from forestslam._core import StemCentreLmResult

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
    # A fallback gave the pose: another initial pose, the in-sweep rescue or a relocalization.
    fallback: bool = False
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
    # Why the frame did not join the map ("" when it did, see _unmerged_reason).
    reason: str = ""


@dataclass
class TlsRun:
    """Result: per-frame records (poses T_tls_sensor), the merged map (M,3) in the TLS frame,
    the reference (R,3), registered stem centres of accepted frames (list of (V,3))."""

    frames: list[FrameRecord]
    map_points: np.ndarray
    reference: np.ndarray
    frame_centres: list[np.ndarray] = field(default_factory=list)
    # Per map point (M,) the merges that fell in its voxel (the reference and each batch of
    # MapConfig.rebuild_every_frames frames count once); None: not known (all 1). Stems are
    # measured with each point counted that often (trees.plot_trees' weights).
    map_counts: np.ndarray | None = None
    initial_method: str = ""
    # Frames that got no pose: (stamp, reason).
    unplaced: list[tuple[float, str]] = field(default_factory=list)

    @property
    def stamps(self) -> np.ndarray:
        return np.array([f.stamp for f in self.frames])

    @property
    def poses(self) -> np.ndarray:
        return np.array([f.T_tls_sensor for f in self.frames]).reshape(-1, 4, 4)

    @property
    def views(self) -> np.ndarray:
        """x-y positions (P,2) the merged frames were scanned from (mid-sweep): where the map's
        mobile points were seen from (trees.plot_trees fits their stems under range noise)."""
        return np.array([f.T_tls_mid[:2, 3] for f in self.frames if f.accepted]).reshape(-1, 2)


def _check_reference(reference: np.ndarray) -> np.ndarray:
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(ref).all(axis=1)
    if not finite.all():  # a plot scan holds millions of points: no copy when all are valid
        ref = ref[finite]
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


def merged_range_m(config: TlsConfig) -> float:
    """Largest range (m) of the frame points that join the map (MapConfig.merge_max_range_m
    within the frame's own range limit)."""
    return min(config.map.frame_max_range_m, config.map.merge_max_range_m)


def _merged_points(points: np.ndarray, config: TlsConfig) -> np.ndarray:
    """The frame points (N,3) that join the map: all of them unless MapConfig.merge_max_range_m
    is below the frame's own range limit. Without a cap the points are not filtered again: the
    frame's points are deskewed, so their norms differ from the ranges the limit was applied to,
    and a second cut at the same limit would drop a few edge points and change the map."""
    if config.map.merge_max_range_m >= config.map.frame_max_range_m:
        return points
    return points[np.linalg.norm(points, axis=1) <= config.map.merge_max_range_m]


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


class _VoxelCloud:
    """A voxelized cloud that grows: one point per voxel, the mean of what was merged into it
    (each merge's voxel centroid counts once). Merging costs the new points only (sorted
    voxel keys, binary search), not a re-voxelization of the whole map. New voxels wait in a
    small sorted side store and join the main arrays only when it has grown to SIDE_FRACTION
    of them or the points are read: each insert into the main arrays copies all of them (a
    plot map holds millions of voxels), so a long walk copied them at every merge."""

    SIDE_FRACTION = 0.25

    def __init__(self, points: np.ndarray, voxel_m: float, core):
        self.voxel_m = voxel_m
        self.core = core
        pts = self._down(points)
        self._side = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
        if voxel_m <= 0:
            self._main = (np.zeros(0, np.int64), pts, np.zeros(0))
            return
        keys = voxel_keys(pts, voxel_m)
        order = np.argsort(keys)
        # (sorted keys, points, merge counts); each voxel lives in main or side, never both.
        self._main = (keys[order], pts[order], np.ones(len(keys)))

    @property
    def points(self) -> np.ndarray:
        self._consolidate()
        return self._main[1]

    @property
    def counts(self) -> np.ndarray:
        """Per point of `points` (N,) how many merges fell in its voxel (the first cloud and
        each merged batch count once; all 1 without voxels): how often it was observed."""
        self._consolidate()
        return self._main[2] if self.voxel_m > 0 else np.ones(len(self._main[1]))

    @property
    def keys(self) -> np.ndarray:
        """The sorted voxel keys (N,) of `points` (voxelized clouds only)."""
        self._consolidate()
        return self._main[0]

    def __len__(self) -> int:
        return len(self._main[1]) + len(self._side[1])

    def _down(self, points: np.ndarray) -> np.ndarray:
        if self.voxel_m <= 0:
            return np.ascontiguousarray(points)
        return self.core.voxel_downsample(np.ascontiguousarray(points), self.voxel_m)

    def merge(self, points: np.ndarray) -> None:
        new = self._down(points)
        if self.voxel_m <= 0:
            self._main = (self._main[0], np.concatenate([self._main[1], new]), self._main[2])
            return
        keys = voxel_keys(new, self.voxel_m)
        known = _update_voxels(self._main, keys, new)
        keys, new = keys[~known], new[~known]
        known = _update_voxels(self._side, keys, new)
        # New voxels: into the side store in key order.
        order = np.argsort(keys[~known])
        self._side = _insert_voxels(
            self._side, keys[~known][order], new[~known][order], np.ones(len(order))
        )
        if len(self._side[0]) > self.SIDE_FRACTION * len(self._main[0]):
            self._consolidate()

    def points_where(self, select: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """The points (in `points` order) for which select(points (K,3)) -> (K,) bool holds,
        without consolidating: main's and the side store's selections merged in key order
        (the side store joins main only when it has grown; each join copies the whole map)."""
        main, side = self._main, self._side
        keep = select(main[1])
        if not len(side[0]):
            return main[1][keep]
        keep_side = select(side[1])
        at = np.searchsorted(main[0][keep], side[0][keep_side])
        return np.insert(main[1][keep], at, side[1][keep_side], axis=0)

    def _consolidate(self) -> None:
        if len(self._side[0]):
            self._main = _insert_voxels(self._main, *self._side)
            self._side = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))


def _update_voxels(store, keys: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The running mean of the store's (keys, points, counts) voxels that new points (one per
    voxel, keys (N,)) fall in, updated in place -> which of them fell in one (N,) bool."""
    skeys, spoints, scount = store
    if len(skeys) == 0:
        return np.zeros(len(keys), bool)
    # Sorted queries: the binary searches walk the map's keys in order (cache-friendly).
    by_key = np.argsort(keys, kind="stable")
    pos = np.empty(len(keys), dtype=np.int64)
    pos[by_key] = np.searchsorted(skeys, keys[by_key])
    pos = np.clip(pos, 0, len(skeys) - 1)
    known = skeys[pos] == keys
    j = pos[known]
    c = scount[j]
    spoints[j] = (spoints[j] * c[:, None] + new[known]) / (c + 1)[:, None]
    scount[j] = c + 1
    return known


def _insert_voxels(store, keys: np.ndarray, points: np.ndarray, count: np.ndarray):
    """The store with voxels (sorted keys, not in the store) inserted in key order (one pass
    over the store, no re-sort)."""
    at = np.searchsorted(store[0], keys)
    return (
        np.insert(store[0], at, keys),
        np.insert(store[1], at, points, axis=0),
        np.insert(store[2], at, count),
    )


class _GlobalMap:
    """TLS reference + accepted frames, voxelized (merged in batches), and the local LM
    target, cropped around the predicted frame (x-y disc, height band of the frame) and
    rebuilt only when the frame leaves the crop or the map grew. The target is the whole map
    at target_voxel_m (MapConfig.lm_target "map"), or ("confirmed") the reference at that
    size plus only those merged voxels that no reference voxel touches and that at least
    target_min_merges merge batches filled: the whole map doubles along a walk and thickens
    the stem walls the reference already holds, so each LM round costs more and converges
    less often."""

    def __init__(self, reference: np.ndarray, config: TlsConfig):
        self.core = _core()
        self.config = config
        m = config.map
        self.fine = _VoxelCloud(reference, m.voxel_m, self.core)
        self.target_m = max(m.target_voxel_m, m.voxel_m)
        ref_target = _VoxelCloud(self.fine.points, self.target_m, self.core)
        self._ref_keys, self._ref_target = ref_target.keys, ref_target.points
        # "confirmed": the merged voxels away from the reference; "map": the whole map.
        self._mobile: _VoxelCloud | None = None
        if m.lm_target == "map":
            self._mobile = _VoxelCloud(self.fine.points, self.target_m, self.core)
        self.pending: list[np.ndarray] = []
        self.target = None
        self.target_points = np.zeros((0, 3))  # the target's points (K,3)
        self.target_centre = np.zeros(2)
        self.target_z = (0.0, 0.0)
        self.dirty = True

    @property
    def points(self) -> np.ndarray:
        return self.fine.points

    @property
    def counts(self) -> np.ndarray:
        return self.fine.counts

    @property
    def reference_target(self) -> np.ndarray:
        """The reference voxelized at the target's voxel size (M,3), in voxel-key order."""
        return self._ref_target

    def add(self, points_tls: np.ndarray) -> None:
        self.pending.append(self.core.voxel_downsample(points_tls, self.config.map.voxel_m))
        if len(self.pending) >= self.config.map.rebuild_every_frames:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        new = np.concatenate(self.pending)
        self.pending.clear()
        self.fine.merge(new)
        if len(self.fine) > self.config.map.max_points:
            raise ProcessingError(
                f"the merged map exceeds {self.config.map.max_points} points; "
                "raise map.voxel_m or map.max_points"
            )
        if self.config.map.lm_target == "map":
            self._mobile.merge(new)
            self.dirty = True
            return
        away = self._away_from_reference(self.core.voxel_downsample(new, self.target_m))
        if self._mobile is None:
            self._mobile = _VoxelCloud(away, self.target_m, self.core)
        else:
            self._mobile.merge(away)
        self.dirty = True

    def _away_from_reference(self, voxels: np.ndarray) -> np.ndarray:
        """The voxel centroids (one per target voxel) whose voxel and its neighbours within
        target_reference_margin_voxels hold no reference voxel."""
        reach = self.config.map.target_reference_margin_voxels
        keys = voxel_keys(voxels, self.target_m)
        order = np.argsort(keys, kind="stable")  # sorted queries walk the reference in order
        keys = keys[order]
        near = np.zeros(len(keys), bool)
        span = range(-reach, reach + 1)
        ref = self._ref_keys
        # Per x-y neighbour one search: its column's voxels within reach in z are consecutive
        # keys, so a reference key in [probe - reach, probe + reach] is a neighbour.
        for di, dj in itertools.product(span, span):
            probe = keys + key_step(di, dj)
            at = np.minimum(np.searchsorted(ref, probe - reach), len(ref) - 1)
            near |= (ref[at] >= probe - reach) & (ref[at] <= probe + reach)
        return voxels[order[~near]]

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

        r = m.target_radius_m
        # Keys sort by x voxel first: the disc's x range is one slice of a key-sorted cloud.
        x_range = (xy[0] - r - self.target_m, xy[0] + r + self.target_m)

        def crop(c: np.ndarray) -> np.ndarray:
            keep = (c[:, 2] >= zlo) & (c[:, 2] <= zhi)  # the height band first: fewer distances
            band = np.flatnonzero(keep)
            keep[band] = np.sum((c[band, :2] - xy) ** 2, axis=1) <= r**2
            return keep

        parts = []
        if m.lm_target == "confirmed":
            ref = self._ref_target[x_slab(self._ref_keys, x_range, self.target_m)]
            parts.append(ref[crop(ref)])
        if self._mobile is not None:
            mobile = self._mobile
            slab = x_slab(mobile.keys, x_range, self.target_m)
            pts, counts = mobile.points[slab], mobile.counts[slab]
            confirmed = counts >= (m.target_min_merges if m.lm_target == "confirmed" else 1)
            parts.append(pts[crop(pts) & confirmed])
        self.target_points = np.ascontiguousarray(np.concatenate(parts))
        self.target = self.core.StemCentreTarget(self.target_points)
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


def trust_failure(lm: StemCentreLmResult, T_pred: np.ndarray | None, config: TlsConfig) -> str:
    """Why an LM result is not trusted ("" when it is): not converged, degenerate, real
    residuals too high, or (T_pred given) a correction too large for the motion model."""
    reg = config.registration
    if not lm.converged:
        return "LM did not converge"
    if lm.degenerate:
        return "LM degenerate"
    if lm.real_inliers > 0 and lm.real_rms_m > reg.good_real_rms_m:
        return f"real-feature residual {100 * lm.real_rms_m:.1f} cm"
    if T_pred is not None:
        return _correction_failure(lm, T_pred, config)
    return ""


def _correction_failure(lm: StemCentreLmResult, T_pred: np.ndarray, config: TlsConfig) -> str:
    """Why the LM's correction from the prediction is too large for the motion model ("")."""
    reg = config.registration
    dt, dr = _correction(T_pred, lm.T_target_source)
    if dt > reg.max_correction_m or dr > reg.max_correction_deg:
        return f"correction {dt:.2f} m / {dr:.1f} deg from the prediction"
    return ""


def _trusted(lm: StemCentreLmResult, T_pred: np.ndarray | None, config: TlsConfig) -> bool:
    return not trust_failure(lm, T_pred, config)


def _lm(
    core,
    target,
    feats,
    T_init,
    config: TlsConfig,
    centre_times=None,
    real_times=None,
    cache=None,
    **options,
) -> StemCentreLmResult:
    """The stem-centre LM with the lm_* options of config, then `options` (C++ field names);
    cache: a StemCentreLmCache of the frame (same result, its pair candidates reused)."""
    return core.register_stem_centre_lm(
        target,
        feats.centres,
        feats.radii,
        feats.real_points,
        np.ascontiguousarray(T_init),
        lm_config(config.registration, **options),
        centre_times=centre_times,
        real_times=real_times,
        cache=cache,
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
        if self.target is None:  # the reference is the map's coarse copy: voxelized already
            self.target = core.StemCentreTarget(self.reference)
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
        dt, dr = _correction(T, r.T_target_source)
        ok = (
            bool(r.converged)
            and not r.degenerate
            and dt <= m.accept_reference_max_m
            and dr <= m.accept_reference_max_deg
        )
        return ok, {"lm": r, "correction_m": dt, "correction_deg": dr}


def _sweep_lm(
    lm: StemCentreLmResult, feats, points, times, t_mid: float, lm_at, config: TlsConfig, ms: dict
):
    """The trusted rigid result lm refined with the motion during the sweep (see tls.sweep)
    -> (LM result, features moved by that motion into the registration frame, sweep (K,6)),
    or None when the refined LM is not trusted (then the rigid result stands)."""
    reg = config.registration
    t0 = time.process_time()
    real = feats.real_points
    tau_c = feature_times(feats.centres, points, times) - t_mid
    tau_r = feature_times(real, points, times) - t_mid
    ms["features"] += (time.process_time() - t0) * 1e3
    T0 = np.asarray(lm.T_target_source)
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
    T, sweep = np.asarray(result.T_target_source), np.asarray(result.sweep)
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
    """Most frame stems, moved by T, lie on a reference stem: within coarse_inlier_m, the
    distance at which the coarse alignment counts a stem as agreeing. A test for gross
    errors (a wrong minimum, a frame placed on wrongly merged frames: stems a stem spacing
    off), not for centimetres: a frame's stems are ring circle fits of one side of the trunk,
    whose centres lie 5-10 cm off the TLS stems' (their own one-sided fits) for frames within
    1 cm of the truth (bench/tls_bench.py plots), and whose radii are off by up to 15 cm on
    short arcs, so neither a 10 cm gate nor a radius test can tell a correct pose from a
    wrong one. The centimetres are checked on the reference's points (_ReferenceCheck). At
    forest densities (0.02-0.1 stems per m^2) a stem falls within 0.35 m of some reference
    stem by chance with probability below 4 %."""
    ref_xyz, _ = ref_stems
    if len(feats.stems) == 0 or len(ref_xyz) == 0:
        return False
    xy = transform_xy(T, feats.stems[:, :2])
    d = np.linalg.norm(xy[:, None, :] - ref_xyz[None, :, :2], axis=2)
    hit = d.min(axis=1) < config.registration.coarse_inlier_m
    need = max(config.registration.coarse_min_stems, int(np.ceil(0.5 * len(xy))))
    return int(hit.sum()) >= need


def _unmerged_reason(
    good: bool,
    failure: str,
    stems_agree: bool,
    lm: StemCentreLmResult,
    on_reference: bool,
    relocalized: bool,
    swept: bool,
    accepted: bool,
    ref_dt: float,
    ref_dr: float,
) -> str:
    """Why a registered frame did not join the map ("" when it did)."""
    if accepted:
        return ""
    if not good:
        return f"not trusted: {failure}"
    if not stems_agree:
        return (
            f"stem pairs too few or loose ({lm.virtual_inliers} pairs, "
            f"{100 * lm.virtual_rms_m:.1f} cm RMS)"
        )
    if not on_reference:
        return "its stems are not on the reference's stems"
    if relocalized:
        return "relocalized after tracking loss (placed afresh, not merged)"
    if not swept:
        return "in-sweep motion not estimated"
    # One reason kind for the summary, the figures in parentheses (see unmerged_summary).
    return f"does not hold on the reference alone (moved {100 * ref_dt:.1f} cm / {ref_dr:.2f} deg)"


def _record(stamp, T_stamp, lm, ms, reason: str = "", **fields) -> FrameRecord:
    return FrameRecord(
        stamp=float(stamp),
        T_tls_sensor=np.asarray(T_stamp),
        accepted=not reason,
        converged=bool(lm.converged),
        degenerate=bool(lm.degenerate),
        virtual_inliers=int(lm.virtual_inliers),
        virtual_rms_m=float(lm.virtual_rms_m),
        real_inliers=int(lm.real_inliers),
        real_rms_m=float(lm.real_rms_m),
        ms_features=ms["features"],
        ms_lm=ms["lm"],
        ms_ndt=ms["ndt"],
        ms_target=ms["target"],
        reason=reason,
        **fields,
    )


def _backfill(init: Initializer, T_latest: np.ndarray, lm_with, on_reference, config: TlsConfig):
    """Records of the frames before the placed one (same odometry segment), in time order:
    chained back through the NDT odometry from the placed pose, each refined by the LM
    against the map when trusted and its stems then sit on the reference's stems
    (on_reference(feats, T) -> bool; a wrong minimum, e.g. few stems in view, moves them a
    stem spacing off). Never merged. Also (T_tls_mid, mid-sweep time) of the frame
    just before the placed one when its LM was trusted (a velocity for the placed frame), else
    None."""
    pending = [f for f in init.pending[:-1] if f.segment == init.pending[-1].segment]
    T_next, L_next, t_next = T_latest, init.pending[-1].T_local, None
    out, seed = [], None
    for f in reversed(pending):
        T_guess = T_next @ np.linalg.inv(L_next) @ f.T_local
        t0 = time.process_time()
        lm = lm_with(T_guess, f.feats, f.z_points)
        f.ms["lm"] += (time.process_time() - t0) * 1e3
        failure = trust_failure(lm, T_guess, config)
        if not failure and not on_reference(f.feats, np.asarray(lm.T_target_source)):
            failure = "its stems are not on the reference's stems"
        T = np.asarray(lm.T_target_source) if not failure else T_guess
        t_ref = f.stamp + f.t_mid_s
        twist = np.zeros(6)
        if t_next is not None and t_next > t_ref:
            twist = se3_log(np.linalg.inv(T) @ T_next) / (t_next - t_ref)
        reason = "before the walk was placed (pose chained back by odometry" + (
            ", LM refined)" if not failure else f"; LM: {failure})"
        )
        out.append(
            _record(
                f.stamp,
                T @ se3_exp(-twist * f.t_mid_s),
                lm,
                f.ms,
                reason,
                t_mid_s=f.t_mid_s,
                T_tls_mid=T,
            )
        )
        if t_next is None and not failure:
            seed = (T, t_ref)
        T_next, L_next, t_next = T, f.T_local, t_ref
    return out[::-1], seed


def register_mls_to_tls(
    scans: Iterable[Scan],
    reference: np.ndarray,
    config: TlsConfig | None = None,
    initial_pose: np.ndarray | None = None,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> TlsRun:
    """Register MLS scans (sensor frame, ring when available) onto a TLS reference (R,3).
    initial_pose (4,4) T_tls_sensor of the first frame, or None to place the walk by its
    stems (see tls.initialize; every frame is tried until one is placed).
    Raises InputError for an unusable reference or no frames, ProcessingError when no frame
    of the walk can be placed in the reference (mismatched data) or the given initial pose
    does not register."""
    config = config or TlsConfig()
    walk = _Walk(_check_reference(reference), config, initial_pose, on_frame)
    for index, scan in enumerate(scans):
        if index % max(1, config.frame_step) == 0:
            walk.add(index, scan)
    return walk.finish()


@dataclass
class _Frame:
    """One MLS frame on its way through the pipeline: usable points (deskewed to mid-sweep),
    rings, per-point times, features and the CPU time spent on it."""

    index: int
    stamp: float
    t_mid: float  # registration time: mid-sweep, seconds after the stamp
    t_ref: float  # stamp + t_mid
    points: np.ndarray
    rings: np.ndarray | None
    times: np.ndarray | None
    feats: FrameFeatures
    ms: dict
    deskew_twist: np.ndarray  # the motion model's velocity it was deskewed with (6,)
    # Pair candidates shared by the frame's LM calls on the map target (StemCentreLmCache).
    lm_cache: object = None


@dataclass
class _Registration:
    """How a frame was registered: the LM result, the initial pose it started from, the
    prediction it is checked against (None before the walk is anchored), trusted or why not."""

    lm: StemCentreLmResult
    T_init: np.ndarray
    T_pred: np.ndarray | None
    failure: str
    fallback: bool = False
    relocalized: bool = False
    seed: tuple[np.ndarray, float] | None = None  # placed frame: the frame before it (T, t)
    # Set when the in-sweep LM already ran in _register (_rescue_in_sweep): (features, sweep).
    swept: tuple[FrameFeatures, np.ndarray] | None = None

    @property
    def good(self) -> bool:
        return not self.failure


class _Walk:
    """The walk's registration state: the growing map, the motion model (the odometry's
    forestslam::odometry::ConstantVelocityModel), the placement of the walk and the records.
    add() runs one frame through the stages; finish() returns the TlsRun."""

    def __init__(self, ref: np.ndarray, config: TlsConfig, initial_pose, on_frame):
        self.core = _core()
        self.config = config
        self.ref = ref
        self.gmap = _GlobalMap(ref, config)
        # The reference voxelized as the map's coarse copy (before any frame joins): the
        # target of the acceptance test and the ground heights of the placement.
        self.ref_coarse = self.gmap.reference_target
        self.check_reference = _ReferenceCheck(self.ref_coarse, config)
        self.initial_pose = initial_pose
        self.on_frame = on_frame
        self.method = "given" if initial_pose is not None else "stems"
        self._ref_stems = None
        self.init: Initializer | None = None
        self.frames: list[FrameRecord] = []
        self.unplaced: list[tuple[float, str]] = []
        self.centres: list[np.ndarray] = []
        # The velocity (deskew, prediction, NDT guess) only while fresh: a longer gap since
        # the last trusted frame restarts the model (RegistrationConfig.max_velocity_age_s).
        self.motion = self.core.ConstantVelocityModel(motion_model_config(config.registration))
        self.anchored = False  # the walk has a pose in the TLS frame
        self.lost = 0  # consecutive frames that did not join the map
        self.verified = False  # the current frame's stems sit on the reference's (_merge)
        # The motion model's velocity (twist) at the last verified frame: the velocity the
        # frames after a relocalization may try (_verified_velocity_pose).
        self.verified_velocity: np.ndarray | None = None
        self.T_prev = None  # previous frame's pose (trusted or not) and points: NDT chain
        self.prev_points = None
        self.seen = 0
        # Before the placement: the NDT odometry of the pending frames (local frame).
        self.T_local, self.rel_local = np.eye(4), np.eye(4)

    # -- the stages of one frame ------------------------------------------------------------

    def add(self, index: int, scan: Scan) -> None:
        self.seen += 1
        frame = self._prepare(index, scan)
        if frame is None:
            return
        reg = self._register(frame) if self.anchored else self._place(frame)
        if reg is None:
            return
        reg, sweep = self._refine_in_sweep(frame, reg)
        T = self._pose(reg)
        accepted, reason, ref_dt, ref_dr = self._merge(frame, reg, sweep, T)
        self._update_motion(frame, reg, T)
        self._emit(frame, reg, sweep, T, reason, ref_dt, ref_dr)
        self.T_prev, self.prev_points = T, frame.points

    def finish(self) -> TlsRun:
        if self.seen == 0:
            raise InputError("the MLS input holds no scans")
        if not self.frames:
            raise ProcessingError(_unplaced_message(self.seen, self.init))
        self.gmap.flush()
        return TlsRun(
            frames=bridge_unmerged(self.frames, self.config.registration.bridge_max_gap_s),
            map_points=self.gmap.points,
            reference=self.ref,
            map_counts=self.gmap.counts,
            frame_centres=self.centres,
            initial_method=self.method,
            unplaced=self.unplaced,
        )

    def _prepare(self, index: int, scan: Scan) -> _Frame | None:
        """Usable points, deskewed to mid-sweep by the motion model, and features; None (and
        the frame listed as unplaced) when too few points are left."""
        points, rings, times = _frame_points_times(scan, self.config)
        if len(points) < 100:
            log.warning(
                "frame %d at %.3f has %d usable points: skipped", index, scan.stamp, len(points)
            )
            self.unplaced.append((float(scan.stamp), f"no pose: {len(points)} usable points"))
            return None
        # Spinning scans are deskewed to, and registered at, the middle of their sweep: a
        # velocity error then distorts the frame symmetrically; the pose at the stamp is
        # extrapolated from it afterwards.
        t_mid = 0.0 if times is None else float(0.5 * (times.min() + times.max()))
        t_ref = float(scan.stamp) + t_mid
        self.motion.begin_scan(t_ref)
        twist = np.array(self.motion.twist) if self.motion.initialised else np.zeros(6)
        t0 = time.process_time()
        if times is not None and np.any(twist):
            points = np.asarray(self.motion.deskew(points, times - t_mid))
        feats = frame_features(points, rings, self.config.features)
        ms = {"features": (time.process_time() - t0) * 1e3, "ndt": 0.0, "target": 0.0, "lm": 0.0}
        return _Frame(
            index,
            float(scan.stamp),
            t_mid,
            t_ref,
            points,
            rings,
            times,
            feats,
            ms,
            twist,
            self.core.StemCentreLmCache(),
        )

    def _lm(
        self, T_start: np.ndarray, feats, z_points, ms=None, cache=None, **options
    ) -> StemCentreLmResult:
        """LM of features from T_start against the map target cropped around it."""
        t0 = time.process_time()
        target, _ = self.gmap.target_at(T_start[:2, 3], _z_range(z_points, T_start))
        t1 = time.process_time()
        result = _lm(self.core, target, feats, T_start, self.config, cache=cache, **options)
        if ms is not None:
            ms["target"] += (t1 - t0) * 1e3
            ms["lm"] += (time.process_time() - t1) * 1e3
        return result

    def _lm_at(self, frame: _Frame, T_start: np.ndarray, **options) -> StemCentreLmResult:
        return self._lm(T_start, frame.feats, frame.points, frame.ms, frame.lm_cache, **options)

    def _ndt(self, frame: _Frame, V: np.ndarray) -> np.ndarray | None:
        """The relative pose T_prev_frame by NDT against the previous frame's points from the
        guess V, or None."""
        t0 = time.process_time()
        ndt = self.core.register_ndt(
            self.prev_points,
            frame.points,
            np.ascontiguousarray(V),
            ndt_config(self.config.registration),
        )
        frame.ms["ndt"] += (time.process_time() - t0) * 1e3
        return np.asarray(ndt.T_target_source) if ndt.converged else None

    @property
    def ref_stems(self):
        if self._ref_stems is None:
            self._ref_stems = reference_stems(self.ref, self.config.features)
            log.info("reference: %d stems", len(self._ref_stems[0]))
        return self._ref_stems

    def _place(self, frame: _Frame) -> _Registration | None:
        """The walk's first pose: the given initial pose (must register), else the frames so
        far placed by their stems (tls.initialize); the frames before the placed one get
        poses chained back. None while the walk cannot be placed yet."""
        if self.initial_pose is not None:
            T_init = np.asarray(self.initial_pose, dtype=np.float64)
            lm = self._lm_at(frame, T_init)
            failure = trust_failure(lm, None, self.config)
            if failure:
                raise ProcessingError(
                    "the first MLS frame does not register onto the reference from the given "
                    f"initial pose ({failure}): mismatched data or a wrong initial pose"
                )
            self.anchored = True
            return _Registration(lm, T_init, None, failure)
        placed = self._push_pending(frame)
        if placed is None:
            return None
        for f in self.init.dropped():
            self.unplaced.append((f.stamp, "no pose: odometry broke before the walk was placed"))
        on_reference = lambda feats, T: _stems_on_reference(  # noqa: E731
            feats, T, self.ref_stems, self.config
        )
        records, seed = _backfill(
            self.init, placed.T_tls_sensor, self._lm, on_reference, self.config
        )
        for rec in records:
            self._append(rec)
        self.init.pending.clear()
        self.anchored = True
        failure = trust_failure(placed.lm, None, self.config)
        return _Registration(placed.lm, placed.T_tls_sensor, None, failure, seed=seed)

    def _push_pending(self, frame: _Frame):
        """The frame into the initializer's local stem map (NDT frame-to-frame odometry, the
        last relative motion as the guess; a failure starts a new odometry segment) ->
        the Placement or None."""
        if self.init is None:
            ref_xyz, ref_r = self.ref_stems
            self.init = Initializer(ref_xyz[:, :2], ref_r, self.ref_coarse, self.config)
        ndt_ok = True
        if self.prev_points is not None:
            T_rel = self._ndt(frame, self.rel_local)
            ndt_ok = T_rel is not None
            self.T_local = self.T_local @ T_rel if ndt_ok else np.eye(4)
            self.rel_local = T_rel if ndt_ok else np.eye(4)
        pending = PendingFrame(
            frame.index,
            frame.stamp,
            frame.t_mid,
            frame.feats,
            np.ascontiguousarray(frame.points[:: max(1, len(frame.points) // 500)]),
            self.T_local.copy(),
            _ground_z(frame.points),
            frame.ms,
        )
        T_local_prev = self.T_local
        placed = self.init.push(pending, ndt_ok, self._lm)
        # The stem-corrected odometry pose; its motion guesses the next NDT.
        self.T_local = pending.T_local
        if ndt_ok and self.prev_points is not None:
            self.rel_local = np.linalg.inv(T_local_prev) @ self.T_local
        if placed is None:
            self.prev_points = frame.points
        return placed

    def _register(self, frame: _Frame) -> _Registration:
        """The tracked frame: LM from the initial pose (motion-model prediction, or NDT against
        the previous frame in "ndt" mode); when not trusted, the other initial pose; after
        relocalize_after_frames frames off the map, a fresh placement on the reference's stems."""
        reg_cfg = self.config.registration
        T_pred = self._predicted(frame)
        # The motion the prediction implies since the previous frame: the NDT guess.
        V = np.linalg.inv(self.T_prev) @ T_pred
        T_init = T_pred
        if reg_cfg.initial_pose == "ndt":
            rel = self._ndt(frame, V)
            if rel is not None:
                T_pred = T_init = self.T_prev @ rel
        reg = _Registration(self._lm_at(frame, T_init), T_init, T_pred, "")
        reg.failure = trust_failure(reg.lm, T_pred, self.config)
        if not reg.good:
            self._second_initial_pose(frame, reg, V)
        if not reg.good:
            self._verified_velocity_pose(frame, reg)
        if not reg.good:
            self._rescue_in_sweep(frame, reg)
        if self.lost >= reg_cfg.relocalize_after_frames:
            self._relocalize(frame, reg)
        return reg

    def _predicted(self, frame: _Frame) -> np.ndarray:
        """T_tls_sensor at the frame's registration time by the motion model (from the last
        trusted pose)."""
        if not self.motion.initialised:
            return self.T_prev
        return np.asarray(self.motion.predict(frame.t_ref))

    def _second_initial_pose(self, frame: _Frame, reg: _Registration, V: np.ndarray) -> None:
        """Fallback: NDT chained onto the previous frame (velocity mode), or the motion-model
        prediction from the last trusted pose (NDT mode: NDT can fail at sharp turns)."""
        if self.config.registration.initial_pose != "ndt":
            rel = self._ndt(frame, V)
            if rel is None:
                return
            T2 = self.T_prev @ rel
            reg.T_init = T2
        else:
            T2 = self._predicted(frame)
        lm2 = self._lm_at(frame, T2)
        if _trusted(lm2, T2, self.config):
            reg.lm, reg.failure, reg.fallback = lm2, "", True

    def _verified_velocity_pose(self, frame: _Frame, reg: _Registration) -> None:
        """Third initial pose while the model has no velocity (reset by a relocalization):
        the last trusted pose moved on by the velocity of the last verified frame (stems on
        the reference's). A hypothesis the LM must confirm, not a prediction: the machine
        did not stop, but it may have turned since (longleaf-loop-12m-b frames 79-83 after a
        relocalization neither predicted nor deskewed did not converge)."""
        if self.verified_velocity is None or not self.motion.initialised:
            return
        if np.any(np.asarray(self.motion.twist)):
            return
        dt = frame.t_ref - self.motion.time
        T3 = np.asarray(self.motion.pose) @ se3_exp(self.verified_velocity * dt)
        lm3 = self._lm_at(frame, T3)
        if _trusted(lm3, T3, self.config):
            reg.lm, reg.failure, reg.fallback, reg.T_init = lm3, "", True, T3

    def _rescue_in_sweep(self, frame: _Frame, reg: _Registration) -> None:
        """A rigid LM that ran out of rounds without converging (not degenerate, its residual
        and its correction from the prediction within the gates) usually creeps because the
        frame is distorted by motion within its sweep that the deskew got wrong (a turn,
        vibration: the constant velocity of the last frames is not this sweep's): the
        in-sweep LM from it, kept only when it converges within the same gates (trusted from
        the prediction and from the rigid result). Never merged unless it then passes the
        same verification as any frame (_merge)."""
        lm, reg_cfg = reg.lm, self.config.registration
        if not reg_cfg.rescue_in_sweep or frame.times is None or reg_cfg.sweep_order <= 0:
            return
        if lm.degenerate:
            return
        if lm.converged or lm.iterations < reg_cfg.lm_max_rounds:
            return
        if reg.T_pred is not None and _correction_failure(lm, reg.T_pred, self.config):
            return
        if lm.real_inliers > 0 and lm.real_rms_m > reg_cfg.good_real_rms_m:
            return
        lm_at = lambda T, **o: self._lm_at(frame, T, **o)  # noqa: E731
        refined = _sweep_lm(
            lm, frame.feats, frame.points, frame.times, frame.t_mid, lm_at, self.config, frame.ms
        )
        if refined is None or not _trusted(refined[0], reg.T_pred, self.config):
            return
        reg.lm, reg.failure, reg.fallback = refined[0], "", True
        reg.swept = (refined[1], refined[2])

    def _relocalize(self, frame: _Frame, reg: _Registration) -> None:
        """Tracking lost (the last frames did not join the map: untrusted, or trusted but their
        stems off the reference's): the frame placed afresh by its stems on the reference's
        stems; kept when trusted and its stems sit on the reference's."""
        T_c = _coarse_initial_pose(frame.feats, frame.points, self.ref, self.ref_stems, self.config)
        if T_c is None:
            return
        lm2 = self._lm_at(frame, T_c)
        if _trusted(lm2, None, self.config) and _stems_on_reference(
            frame.feats, lm2.T_target_source, self.ref_stems, self.config
        ):
            reg.lm, reg.failure, reg.fallback, reg.relocalized = lm2, "", True, True
            reg.swept = None
            log.info(
                "frame %d at %.3f: relocalized on the reference stems", frame.index, frame.t_ref
            )

    def _refine_in_sweep(self, frame: _Frame, reg: _Registration):
        """A trusted frame registered again with its motion during the sweep (continuous time);
        its points and features are moved with it -> (registration, sweep (K,6) or empty)."""
        sweep = np.zeros((0, 6))
        if reg.swept is not None:
            frame.feats, sweep = reg.swept
            frame.points = apply_sweep(
                frame.points, frame.times - frame.t_mid, reg.lm.T_target_source, sweep
            )
        elif reg.good and frame.times is not None and self.config.registration.sweep_order > 0:
            lm_at = lambda T, **o: self._lm_at(frame, T, **o)  # noqa: E731
            refined = _sweep_lm(
                reg.lm,
                frame.feats,
                frame.points,
                frame.times,
                frame.t_mid,
                lm_at,
                self.config,
                frame.ms,
            )
            if refined is not None:
                reg.lm, frame.feats, sweep = refined
                frame.points = apply_sweep(
                    frame.points, frame.times - frame.t_mid, reg.lm.T_target_source, sweep
                )
        return reg, sweep

    def _pose(self, reg: _Registration) -> np.ndarray:
        """The LM's pose when trusted; in "ndt" mode also when it is not degenerate and either
        converged (as the paper) or was still moving when its rounds ran out: it only descends
        from the initial pose, and a distorted frame of a vibrating scanner creeps on by more
        than the convergence step for many rounds (NDT-chained starts 2-5 deg off ended
        0.1-0.9 deg off after 15 rounds on regular-line-18m, yet the NDT pose was kept and the
        frame lost). Else the initial pose. Only trusted frames join the map or give a
        velocity either way."""
        lm = reg.lm
        ran_out = lm.iterations >= self.config.registration.lm_max_rounds
        lm_ok = (lm.converged or ran_out) and not lm.degenerate
        use_lm = reg.good or (self.config.registration.initial_pose == "ndt" and lm_ok)
        return np.asarray(lm.T_target_source if use_lm else reg.T_init)

    def _merge(self, frame: _Frame, reg: _Registration, sweep: np.ndarray, T: np.ndarray):
        """Whether the frame joins the map (merged when it does) -> (accepted, reason,
        reference correction m, deg). Only frames whose stems sit on the reference's stems
        join: a frame registered onto earlier wrongly placed frames must not spread the
        error. A relocalized frame restarts the tracking but does not join itself (a coarse
        placement can sit in a wrong minimum and still look trusted); a frame joins only when
        its pose also holds on the TLS reference alone (MapConfig.accept_reference_*). With
        per-point times, only a frame whose in-sweep motion was estimated joins: a rigid frame
        of a vibrating scanner is distorted by centimetres (its ground above all)."""
        cfg, lm = self.config, reg.lm
        stems_agree = (
            lm.virtual_inliers >= cfg.map.accept_min_virtual_inliers
            and lm.virtual_rms_m <= cfg.map.accept_virtual_rms_m
        )
        on_reference = (
            reg.good and stems_agree and _stems_on_reference(frame.feats, T, self.ref_stems, cfg)
        )
        swept = len(sweep) > 0 or frame.times is None or cfg.registration.sweep_order <= 0
        accepted = False
        ref_dt = ref_dr = float("nan")
        if on_reference and swept and not reg.relocalized:
            t0 = time.process_time()
            accepted, check = self.check_reference(frame.feats, T)
            frame.ms["lm"] += (time.process_time() - t0) * 1e3
            ref_dt, ref_dr = check["correction_m"], check["correction_deg"]
        self.lost = 0 if on_reference else self.lost + 1
        self.verified = on_reference
        if accepted:
            self.gmap.add(transform_points(T, _merged_points(frame.points, cfg)))
            self.centres.append(transform_points(T, frame.feats.centres))
        reason = _unmerged_reason(
            reg.good,
            reg.failure,
            stems_agree,
            lm,
            on_reference,
            reg.relocalized,
            swept,
            accepted,
            ref_dt,
            ref_dr,
        )
        return accepted, reason, ref_dt, ref_dr

    def _update_motion(self, frame: _Frame, reg: _Registration, T: np.ndarray) -> None:
        """The motion model learns the velocity from consecutive trusted poses only (a bad
        pose would distort the next frames through the deskew); a relocalized frame jumped,
        so the motion from the previous pose is no velocity (the frames after it may try
        the last verified one, _verified_velocity_pose); the placed frame's velocity comes
        from the frame chained back before it (LM refined)."""
        if reg.relocalized:
            self.motion.reset()
        elif reg.seed is not None:
            self.motion.update(reg.seed[1], reg.seed[0], True)
            self.motion.begin_scan(frame.t_ref)
        self.motion.update(frame.t_ref, T, reg.good)
        if self.verified and not reg.relocalized:
            self.verified_velocity = np.array(self.motion.twist)

    def _emit(self, frame, reg, sweep, T, reason, ref_dt, ref_dr) -> None:
        """The frame's record; the pose at the stamp (sweep start) from its own in-sweep
        motion when estimated (on top of the deskew it was estimated after), else
        extrapolated with the velocity."""
        if len(sweep):
            T_stamp = sweep_pose(T, sweep, -frame.t_mid) @ se3_exp(
                -frame.deskew_twist * frame.t_mid
            )
        else:
            twist = np.array(self.motion.twist)
            T_stamp = T @ se3_exp(-twist * frame.t_mid)
        record = _record(
            frame.stamp,
            T_stamp,
            reg.lm,
            frame.ms,
            reason,
            fallback=reg.fallback,
            t_mid_s=frame.t_mid,
            deskew_twist=frame.deskew_twist if frame.times is not None else np.zeros(6),
            T_tls_mid=np.asarray(T),
            relocalized=reg.relocalized,
            reference_correction_m=ref_dt,
            reference_correction_deg=ref_dr,
            sweep=sweep,
        )
        self._append(record)

    def _append(self, record: FrameRecord) -> None:
        self.frames.append(record)
        if self.on_frame is not None:
            self.on_frame(record)


def unmerged_frames(run: TlsRun) -> list[tuple[float, str]]:
    """(stamp, reason) of every frame that did not join the map (with a pose or without),
    in time order."""
    rows = [(f.stamp, f.reason) for f in run.frames if not f.accepted]
    return sorted(rows + list(run.unplaced))


def unmerged_csv(run: TlsRun) -> str:
    """The unmerged frames as CSV text: stamp,has_pose,reason."""
    posed = {f.stamp for f in run.frames}
    lines = ["stamp,has_pose,reason"]
    for stamp, reason in unmerged_frames(run):
        text = reason.replace('"', "'")
        lines.append(f'{stamp:.6f},{int(stamp in posed)},"{text}"')
    return "\n".join(lines) + "\n"


def unmerged_summary(run: TlsRun) -> dict[str, int]:
    """How many frames did not join the map, per reason kind (the reason up to its first
    parenthesis or colon detail, so similar reasons count together)."""
    out: dict[str, int] = {}
    for _, reason in unmerged_frames(run):
        kind = reason.split("; ")[0].split(" (")[0].split(": ")[0] if reason else "unknown"
        out[kind] = out.get(kind, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _ground_z(points: np.ndarray) -> float | None:
    return ground_height_near(points, np.zeros(2))


def _unplaced_message(seen: int, init: Initializer | None) -> str:
    """The error when no frame of the walk could be placed on the reference."""
    if init is None:
        return "no MLS frame could be registered onto the reference"
    b = init.best
    return (
        f"none of the {seen} MLS frames could be placed on the TLS reference by its stems "
        f"({init.attempts} attempts; best: {b.reason}; the reference has "
        f"{len(init.ref_xy)} stems): is the reference from the same plot? "
        "Give --initial-pose if it is"
    )
