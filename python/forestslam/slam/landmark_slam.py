"""Landmark SLAM driver: GTSAM iSAM2 over Pose2 keyframes and Point2 trees.

State: the planar pose (x, y, yaw) of the sensor in the odometry world frame (the first scan's
sensor frame). Observations are stem centres levelled by the odometry's roll and pitch, so a
tilted sensor still gives planar range and bearing. Factors enter at keyframes only:
BetweenFactorPose2 from the odometry motion since the previous keyframe (the summed step
covariances plus a floor) and robust BearingRangeFactor2D to trees. A stem becomes a tree (a
Point2 variable) only after `tentative_min_observations` keyframes saw it at the same place, so
clutter seen once never enters the graph. Re-observing an old tree adds a factor to its old
variable: that closes the loop.

Height: the planar graph leaves z to the odometry; with `height_correction` the trees' centre
heights, re-observed at keyframes, correct the odometry's z drift in a separate linear 1D
graph (`forestslam.slam.height`), applied to `trajectory()` and given by `landmark_heights()`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import gtsam
import numpy as np

from forestslam import geometry
from forestslam.errors import InputError, ProcessingError
from forestslam.slam.association import (
    AssociationResult,
    associate,
    dbh_compatible,
    duplicate_pairs,
    rigid_2d,
)
from forestslam.slam.config import SlamConfig
from forestslam.slam.height import HeightGraph

log = logging.getLogger(__name__)


def X(i: int) -> int:
    return gtsam.symbol("x", i)


def L(j: int) -> int:
    return gtsam.symbol("l", j)


def planar(T: np.ndarray) -> np.ndarray:
    """(x, y, yaw) of a (4,4) pose; yaw of the rotated x axis projected on the plane."""
    return np.array([T[0, 3], T[1, 3], geometry.yaw_of(T)])


def pose2_matrix(p: np.ndarray) -> np.ndarray:
    """Planar pose (3,3) of (x, y, yaw)."""
    return geometry.se2(p[0], p[1], p[2])


def matrix_pose2(m: np.ndarray) -> np.ndarray:
    """(x, y, yaw) of a planar pose (3,3)."""
    return np.array([m[0, 2], m[1, 2], geometry.yaw_of(m)])


def lift(m: np.ndarray) -> np.ndarray:
    """A planar (3,3) transform as a (4,4) rotation about z plus xy translation."""
    t = np.eye(4)
    t[:2, :2] = m[:2, :2]
    t[:2, 3] = m[:2, 2]
    return t


def level_points(T_world_sensor: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Sensor-frame points (N,3) -> the levelled frame: sensor origin, world z up, sensor yaw."""
    R_level_sensor = geometry.rot_z(geometry.yaw_of(T_world_sensor)).T @ T_world_sensor[:3, :3]
    return points @ R_level_sensor.T


def tilt(T: np.ndarray) -> np.ndarray:
    """T (4,4) with its planar part (x, y, yaw) removed: z, roll and pitch remain, so that
    T == lift(pose2_matrix(planar(T))) @ tilt(T)."""
    return geometry.inverse(lift(pose2_matrix(planar(T)))) @ T


@dataclass
class _Tentative:
    xy: np.ndarray  # running mean, map frame
    dbh: list = field(default_factory=list)
    obs: list = field(default_factory=list)  # (keyframe, bearing, range, sigma_b, sigma_r)
    z: list = field(default_factory=list)  # (keyframe, centre z in the odometry frame)
    last_kf: int = 0

    def copy(self) -> _Tentative:
        """An independent copy (what copy.deepcopy gave, at a fraction of its cost): the lists
        hold floats and tuples of numbers, which are immutable."""
        xy, last = self.xy.copy(), self.last_kf
        return _Tentative(xy, list(self.dbh), list(self.obs), list(self.z), last)


@dataclass
class ScanResult:
    keyframe: int | None  # keyframe index when this scan made one
    landmark_ids: np.ndarray  # (K,) tree id per observation, -1 = none
    T_map_sensor: np.ndarray  # (4,4) current best pose of this scan


class LandmarkSlam:
    """Feed scans in order with `add_scan`; read `trajectory()` and `landmarks()` any time."""

    def __init__(self, config: SlamConfig | None = None) -> None:
        self.cfg = config or SlamConfig()
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.cfg.relinearize_threshold)
        params.relinearizeSkip = self.cfg.relinearize_skip
        self._isam_params = params
        self.isam = gtsam.ISAM2(params)
        # What iSAM2 holds after the last successful update: a failed update leaves iSAM2 with
        # its new variables half added, so it is rebuilt from these (see _rebuild_isam).
        self._graph = gtsam.NonlinearFactorGraph()
        self._estimate = gtsam.Values()
        self.failed_updates = 0  # keyframes whose update failed and was rolled back
        # per scan
        self._stamps: list[float] = []
        self._odom: list[np.ndarray] = []  # (4,4)
        self._scan_kf: list[int] = []  # last keyframe at or before the scan
        # per keyframe
        self._kf_scan: list[int] = []
        self._kf_odom2: list[np.ndarray] = []  # planar odometry pose (3,)
        self._kf_est = np.zeros((0, 3))  # optimised planar poses
        # landmarks
        self._lm_xy = np.zeros((0, 2))
        self._lm_nobs = np.zeros(0, dtype=np.int64)
        self._lm_dbh = np.zeros(0)
        self._lm_prior_sigma = np.zeros(0)  # position sigma of a prior-map tree, NaN otherwise
        self._lm_run_obs = np.zeros(0, dtype=np.int64)  # observations made by this run
        self._lm_last_kf = np.zeros(0, dtype=np.int64)  # last keyframe that saw it (-1: none)
        self._lm_first_kf = np.zeros(0, dtype=np.int64)  # first keyframe that saw it (-1: none)
        # sum and count of observed centre heights (the heights without `height_correction`)
        self._lm_zsum = np.zeros(0)
        self._lm_nz = np.zeros(0, dtype=np.int64)
        self._lm_alias = np.zeros(0, dtype=np.int64)  # the older copy a tree was tied to, or -1
        self._tentative: list[_Tentative] = []
        self._kf_lms: list[set[int]] = []  # per keyframe: the trees it observed
        self._cov_acc = np.zeros((3, 3))
        self._dist_acc = 0.0
        self._pose_cov = np.diag([1e-6, 1e-6, 1e-8])
        # Loops closed by verified place recognition (`tie_trees`) only. Re-association that
        # re-found old trees with a large correction is counted apart: on tree tables (whole
        # local maps per frame) it fires at most keyframes and is no evidence of a loop.
        self.loop_closures = 0
        self.reassociation_corrections = 0
        self.merged_duplicates = 0  # tree pairs merged after closures (see _merge_duplicates)
        self.n_landmark_factors = 0
        # Tracking loss (see SlamConfig.loss_*): the first keyframe of the current lost segment,
        # None while tracking holds or once place recognition relocalized the segment.
        self.lost_since: int | None = None
        self.losses = 0
        self.relocalizations = 0
        self._loss_kfs: list[int] = []  # keyframes that started a segment
        # A revisit (see _add_odometry_factor): the keyframe whose scan the consensus moved onto
        # older copies of the tracked trees, for place recognition to verify; and their count.
        self.pending_revisit: int | None = None
        self.revisits = 0
        # Metres added to every observed stem-centre range: a centre fitted to the visible side
        # of a stem sits nearer (or farther) than the axis by a similar amount whatever the
        # tree, so views from opposite sides disagree and bend the trajectory. Estimated online
        # from the range residuals of well-observed trees (see _update_range_offset).
        self.range_offset = 0.0
        c = self.cfg
        self.height = (
            HeightGraph(c.height_obs_sigma_m, c.height_step_sigma_m, c.height_sigma_per_m)
            if c.height_correction
            else None
        )
        # Optional scan-to-map refinement, called at keyframes with the predicted planar pose
        # (3,3); returns a refined planar pose (3,3) and its (3,3) x, y, yaw covariance in the
        # map frame, or None. Its result is added as a second between factor.
        self.refine_hook = None

    # ------------------------------------------------------------------ public
    @property
    def n_keyframes(self) -> int:
        return len(self._kf_scan)

    @property
    def n_landmarks(self) -> int:
        return len(self._lm_xy)

    @property
    def keyframe_scans(self) -> np.ndarray:
        """Scan index (order of `add_scan` calls) of every keyframe."""
        return np.asarray(self._kf_scan, dtype=np.int64)

    def search_radius(self) -> float:
        """The association's search radius at the last keyframe: 3 sigma of its position
        marginal (the pose error the map may carry here), clamped to the configured range."""
        eig = float(np.sqrt(max(np.linalg.eigvalsh(self._pose_cov[:2, :2]).max(), 0.0)))
        return float(np.clip(3.0 * eig, self.cfg.search_radius_min_m, self.cfg.search_radius_max_m))

    def landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """Tree positions (L,2) in the map frame and observation counts (L,)."""
        return self._lm_xy.copy(), self._lm_nobs.copy()

    def landmark_heights(self) -> np.ndarray:
        """Height (L,) of every tree's breast-height centre in the map frame (NaN without height
        data): corrected for the odometry's z drift with `height_correction`, else the mean of
        its observed heights (the prior-map placement levels B's map on them)."""
        if self.height is None:
            with np.errstate(invalid="ignore"):  # 0 / 0: no height seen -> NaN
                return self._lm_zsum / self._lm_nz
        return self.height.solve(self.n_landmarks)[1]

    def _add_heights(self, lms: np.ndarray, z: np.ndarray) -> None:
        """Count the observed centre heights z of landmarks `lms` (one per row)."""
        ok = np.isfinite(z)
        np.add.at(self._lm_zsum, lms[ok].astype(np.int64), z[ok])
        np.add.at(self._lm_nz, lms[ok].astype(np.int64), 1)

    def landmark_sigma(self) -> np.ndarray:
        """Position sigma (L,) of every tree: its observations', combined with its prior's for a
        prior-map tree (an inventory tree is uncertain until this run sees it)."""
        so = self.cfg.observation_sigma_m
        prior = np.isfinite(self._lm_prior_sigma)
        sp = np.where(prior, self._lm_prior_sigma, np.inf)
        n = np.where(prior, self._lm_run_obs, np.maximum(self._lm_nobs, 1))
        info = n / so**2 + 1.0 / sp**2
        return np.maximum(1.0 / np.sqrt(info), self.cfg.landmark_sigma_floor_m)

    def landmark_keyframes(self) -> tuple[np.ndarray, np.ndarray]:
        """(L,) first and (L,) last keyframe that observed each tree (-1: never, a prior-map
        tree this run has not seen)."""
        return self._lm_first_kf.copy(), self._lm_last_kf.copy()

    def aliases(self) -> np.ndarray:
        """(L,) for a tree tied to an older copy of itself by place recognition, that copy's
        index (resolved to the oldest); -1 for the others."""
        alias = self._lm_alias.copy()
        for _ in range(8):  # chains of ties are short
            deeper = (alias >= 0) & (alias[np.maximum(alias, 0)] >= 0)
            if not deeper.any():
                break
            alias[deeper] = alias[alias[deeper]]
        return alias

    def tie_trees(self, pairs: np.ndarray, sigma_m: float) -> None:
        """Place recognition found trees mapped twice: each pair (older, newer) of landmark
        indices is tied by a zero-difference factor (see `_add_ties`), which closes the loop
        (counted in `loop_closures`); the newer copy becomes an alias of the older in the tree
        table."""
        self._tie(pairs, sigma_m)
        self.loop_closures += 1

    def _tie(self, pairs: np.ndarray, sigma_m: float) -> None:
        self._add_ties(pairs, sigma_m, "tying trees", self.cfg.extra_updates_on_loop)
        self._merge_duplicates(sigma_m)

    def _add_ties(self, pairs: np.ndarray, sigma_m: float, what: str, relinearize: int) -> None:
        """Zero-difference factors between the trees of each pair (older, newer); the newer
        becomes an alias of the older. `relinearize` extra iSAM2 iterations follow.
        Not robust: every pair is verified already (the localizer's inliers under its
        acceptance test, or duplicates within the association gate), and when a loop is closed
        the pairs' residuals at the current estimate are the loop's whole error (metres), not
        outliers. A Huber kernel of k sigma bounds each tie's pull to that of a k sigma
        residual, so a few tied trees could not bend the chain back: the simulated loop of
        tests/test_multisession_loop_closure.py on stand seed 5 stayed 3-4 m off after four
        verified closures (ATE 1.13 m; 0.36 m with these ties, seeds 3, 4, 6, 7 unchanged)."""
        before = self._snapshot()
        graph = gtsam.NonlinearFactorGraph()
        noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_m)
        for old, new in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
            graph.add(
                gtsam.BetweenFactorPoint2(L(int(old)), L(int(new)), gtsam.Point2(0, 0), noise)
            )
            self._lm_alias[new] = old
        self._update(graph, gtsam.Values(), before, what)
        for _ in range(relinearize):
            self.isam.update(force_relinearize=True)
        est = self._estimate = self.isam.calculateEstimate()
        self._kf_est = gtsam.utilities.extractPose2(est).reshape(-1, 3)
        self._lm_xy = gtsam.utilities.extractPoint2(est).reshape(-1, 2)

    def _merge_duplicates(self, sigma_m: float) -> None:
        """After a closure: trees the SLAM mapped twice (its prediction was off beyond the
        association gate when it came back) that the closure brought within the gate of each
        other, and that no keyframe observed together, are tied like place recognition's pairs
        (the newer becomes an alias), so later scans re-find one tree, not two."""
        roots = np.flatnonzero(self._lm_alias < 0)
        pairs = duplicate_pairs(
            self._lm_xy, self.landmark_sigma(), self._lm_dbh, roots, self._seen_together, self.cfg
        )
        if len(pairs):
            self._add_ties(pairs, sigma_m, "merging duplicated trees", 0)
            self.merged_duplicates += len(pairs)
            log.info("merged %d duplicated trees after a closure", len(pairs))

    def _seen_together(self, a: int, b: int) -> bool:
        """Whether one keyframe observed both trees a and b."""
        first = np.maximum(self._lm_first_kf[[a, b]], 0)  # a prior-map tree's is -1
        lo, hi = int(first.max()), int(min(self._lm_last_kf[a], self._lm_last_kf[b]))
        if hi < 0 or lo > hi:
            return False
        return any(a in seen and b in seen for seen in self._kf_lms[lo : hi + 1])

    def relocalized(self, pairs: np.ndarray, sigma_m: float) -> None:
        """Place recognition placed the lost segment in the map: its trees (newer) are tied to
        the map's (older) as in `tie_trees`, and association uses every tree again."""
        self._tie(pairs, sigma_m)  # a relocalization, counted apart from loop closures
        self.relocalizations += 1
        self.lost_since = None

    def observed_this_run(self) -> np.ndarray:
        """(L,) whether this run observed each tree (prior-map trees may not have been)."""
        return self._lm_run_obs > 0

    def add_prior_landmarks(
        self,
        xy: np.ndarray,
        dbh: np.ndarray,
        observations: np.ndarray,
        sigma_m: np.ndarray,
        matches: dict[int, int],
    ) -> np.ndarray:
        """Trees of a prior map (M,2) in this graph's frame, with DBH (M,), observation counts
        (M,) and position sigmas (M,): each gets a robust position prior; `matches` {landmark:
        prior index} makes an existing tree that prior tree (counts summed, DBH fused), the
        others become new landmarks. Returns the landmark index of every prior tree."""
        before = self._snapshot()
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ids = np.full(len(xy), -1, dtype=np.int64)
        for lm, j in matches.items():
            ids[j] = lm
        start, new = self.n_landmarks, np.flatnonzero(ids < 0)
        ids[new] = start + np.arange(len(new))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for j, lm in enumerate(ids):
            if lm >= start:
                values.insert(L(int(lm)), gtsam.Point2(*xy[j]))
            noise = self._robust(gtsam.noiseModel.Isotropic.Sigma(2, float(sigma_m[j])))
            graph.add(gtsam.PriorFactorPoint2(L(int(lm)), gtsam.Point2(*xy[j]), noise))
        old = ids[ids < start]
        prior_of_old = np.flatnonzero(ids < start)
        n_old, n_prior = self._lm_nobs[old].astype(np.float64), observations[prior_of_old]
        d_old, d_prior = self._lm_dbh[old], dbh[prior_of_old]
        both = np.isfinite(d_old) & np.isfinite(d_prior)
        self._lm_dbh[old] = np.where(
            both,
            (n_old * d_old + n_prior * d_prior) / (n_old + n_prior),
            np.where(np.isfinite(d_old), d_old, d_prior),
        )
        self._lm_nobs[old] += n_prior.astype(np.int64)
        self._lm_prior_sigma[old] = sigma_m[prior_of_old]
        self._lm_xy = np.vstack([self._lm_xy, xy[new]])
        self._lm_nobs = np.append(self._lm_nobs, observations[new].astype(np.int64))
        self._lm_dbh = np.append(self._lm_dbh, dbh[new])
        self._lm_prior_sigma = np.append(self._lm_prior_sigma, sigma_m[new])
        self._lm_run_obs = np.append(self._lm_run_obs, np.zeros(len(new), dtype=np.int64))
        self._lm_last_kf = np.append(self._lm_last_kf, np.full(len(new), -1, dtype=np.int64))
        self._lm_first_kf = np.append(self._lm_first_kf, np.full(len(new), -1, dtype=np.int64))
        self._lm_zsum = np.append(self._lm_zsum, np.zeros(len(new)))
        self._lm_nz = np.append(self._lm_nz, np.zeros(len(new), dtype=np.int64))
        self._lm_alias = np.append(self._lm_alias, np.full(len(new), -1, dtype=np.int64))
        self._update(graph, values, before, "adding prior trees")
        est = self._estimate = self.isam.calculateEstimate()
        self._kf_est = gtsam.utilities.extractPose2(est).reshape(-1, 3)
        self._lm_xy = gtsam.utilities.extractPoint2(est).reshape(-1, 2)
        return ids

    def add_scan(
        self,
        stamp: float,
        T_odom: np.ndarray,
        covariance: np.ndarray | None,
        degraded: bool,
        stems_xy: np.ndarray,
        stems_dbh: np.ndarray | None = None,
        stems_z: np.ndarray | None = None,
    ) -> ScanResult:
        """One scan: odometry pose T_odom (4,4) with its step covariance (3,3) (x, y, yaw; NaN
        or None = unknown), and the stem centres stems_xy (K,2) in the *levelled* sensor frame
        (see `level_points`) with their DBH (K,) (NaN = unknown) and their heights stems_z (K,)
        in the odometry frame (None / NaN = unknown; used by the height correction)."""
        cfg = self.cfg
        T_odom = np.asarray(T_odom, dtype=np.float64)
        stems_xy = np.asarray(stems_xy, dtype=np.float64).reshape(-1, 2)
        stems_dbh = (
            np.full(len(stems_xy), np.nan)
            if stems_dbh is None
            else np.asarray(stems_dbh, dtype=np.float64).ravel()
        )
        stems_z = (
            np.full(len(stems_xy), np.nan)
            if stems_z is None
            else np.asarray(stems_z, dtype=np.float64).ravel()
        )
        if len(stems_z) != len(stems_xy) or len(stems_dbh) != len(stems_xy):
            raise InputError("add_scan: stems_xy, stems_dbh and stems_z differ in length")
        ok = np.isfinite(stems_xy).all(axis=1)
        rng = np.linalg.norm(stems_xy, axis=1)
        if self.range_offset and len(stems_xy):  # the stem centres' radial bias, see below
            stems_xy = stems_xy * ((rng + self.range_offset) / np.maximum(rng, 1e-9))[:, None]
        ok &= (rng >= cfg.min_observation_range_m) & (rng <= cfg.max_observation_range_m)
        idx = np.nonzero(ok)[0]
        o2 = planar(T_odom)
        first = not self._kf_scan
        self._accumulate_covariance(covariance, degraded, o2)
        self._stamps.append(float(stamp))
        self._odom.append(T_odom.copy())
        ids = np.full(len(stems_xy), -1, dtype=np.int64)

        if first or self._is_keyframe(stamp, o2):
            before = self._snapshot()
            try:
                kf = self._add_keyframe(
                    o2, stems_xy[idx], stems_dbh[idx], stems_z[idx], ids, idx, first
                )
            except ProcessingError:  # forget this scan so the trajectory stays consistent
                self._restore(before)
                del self._stamps[-1], self._odom[-1]
                self.failed_updates += 1
                log.debug("keyframe %d dropped", self.n_keyframes)
                raise
            self._scan_kf.append(kf)
            pose = self._kf_est[kf]
            return ScanResult(kf, ids, lift(pose2_matrix(pose)) @ tilt(T_odom))
        self._scan_kf.append(self.n_keyframes - 1)
        pred = self._predict(o2)
        if len(idx) and self.n_landmarks:
            obs = geometry.transform_xy(pred, stems_xy[idx])
            res = self._associate(
                obs, stems_dbh[idx], np.eye(2) * cfg.search_radius_min_m**2 / 9, False
            )
            ids[idx] = res.matches
            pred = self._localize(obs, res.matches) @ pred
        return ScanResult(None, ids, lift(pred) @ tilt(T_odom))

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Stamps (N,) and optimised poses (N,4,4) of every scan so far, map frame.

        Keyframe corrections (optimised pose composed with the inverse odometry pose) are
        interpolated linearly in time between keyframes and applied to the odometry poses.
        """
        n = len(self._stamps)
        if n == 0:
            return np.zeros(0), np.zeros((0, 4, 4))
        stamps = np.asarray(self._stamps)
        odom = np.stack(self._odom)
        kf_scan = np.asarray(self._kf_scan)
        corr = np.stack(
            [
                matrix_pose2(pose2_matrix(e) @ np.linalg.inv(pose2_matrix(o)))
                for e, o in zip(self._kf_est, self._kf_odom2, strict=True)
            ]
        )
        corr[:, 2] = np.unwrap(corr[:, 2])
        kf_t = stamps[kf_scan]
        c = np.column_stack([np.interp(stamps, kf_t, corr[:, i]) for i in range(3)])
        for k in self._loss_kfs:  # the jump is the lost keyframe's scan: no blending across it
            c[kf_scan[k - 1] + 1 : kf_scan[k]] = corr[k - 1]
        lifts = np.tile(np.eye(4), (n, 1, 1))
        lifts[:, :2, :2] = geometry.rot2(c[:, 2])
        lifts[:, :2, 3] = c[:, :2]
        if self.height is not None:
            dz = self.height.solve(self.n_landmarks)[0]
            lifts[:, 2, 3] = np.interp(stamps, kf_t, dz)
        return stamps, np.einsum("nij,njk->nik", lifts, odom)

    def odometry(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._stamps:
            return np.zeros(0), np.zeros((0, 4, 4))
        return np.asarray(self._stamps), np.stack(self._odom)

    # ---------------------------------------------------------------- internals
    def _accumulate_covariance(self, cov, degraded: bool, o2: np.ndarray) -> None:
        cov = None if cov is None else np.asarray(cov, dtype=np.float64)
        if cov is None or cov.shape != (3, 3) or not np.isfinite(cov).all():
            cov = np.diag([0.05**2, 0.05**2, math.radians(1.0) ** 2])
        # A degenerate registration may report an enormous (or indefinite) covariance: clip its
        # eigenvalues so the factor neither vanishes (an indeterminate graph) nor dominates.
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        w = np.clip(w, 1e-10, self.cfg.odom_max_sigma_step**2)
        cov = (v * w) @ v.T
        if degraded:
            cov = cov * self.cfg.degraded_inflation**2
        self._cov_acc = self._cov_acc + cov
        if self._odom:
            self._dist_acc += float(np.linalg.norm(o2[:2] - planar(self._odom[-1])[:2]))

    def _is_keyframe(self, stamp: float, o2: np.ndarray) -> bool:
        cfg = self.cfg
        last = self._kf_odom2[-1]
        d = float(np.linalg.norm(o2[:2] - last[:2]))
        dyaw = abs((o2[2] - last[2] + math.pi) % (2 * math.pi) - math.pi)
        dt = stamp - self._stamps[self._kf_scan[-1]]
        return (
            d >= cfg.keyframe_distance_m
            or dyaw >= math.radians(cfg.keyframe_yaw_deg)
            or (dt >= cfg.keyframe_max_interval_s and d >= 0.1 * cfg.keyframe_distance_m)
        )

    def _associate(self, obs_map, obs_dbh, pose_cov, use_consensus: bool = True):
        """`associate` with the trees this run may match now: not the second copies tied to an
        older one, and only the lost segment's own trees while it is not relocalized."""
        usable = self._lm_alias < 0
        if self.lost_since is not None:
            usable &= self._lm_first_kf >= self.lost_since
        ids = np.flatnonzero(usable)
        res = associate(
            obs_map,
            obs_dbh,
            self._lm_xy[ids],
            self.landmark_sigma()[ids],
            self._lm_dbh[ids],
            pose_cov,
            self.cfg,
            use_consensus,
        )
        hit = res.matches >= 0
        res.matches[hit] = ids[res.matches[hit]]
        return res

    def _tracked_in_range(self, kf: int, pred: np.ndarray, n_obs: int) -> np.ndarray:
        """The trees (alias roots) tracked at the previous keyframe that should still be seen
        from the prediction pred (3,3), when the loss rule applies (see SlamConfig.loss_*), else
        none. Never while already lost: the segment is free of the chain already; declaring a
        loss again only cut the segment into pieces (Wild-Places V04 tree tables: losses at 5
        consecutive keyframes 449-453, each finding 0 of 6-23 tracked trees)."""
        cfg = self.cfg
        none = np.zeros(0, dtype=np.int64)
        if cfg.loss_min_tracked == 0 or n_obs < cfg.loss_min_tracked or self.lost_since is not None:
            return none
        root = self._roots()  # a tree tied since is tracked as its older copy
        tracked = np.unique(root[self._lm_last_kf == kf - 1])
        rng = np.linalg.norm(self._lm_xy[tracked] - pred[:2, 2], axis=1)
        tracked = tracked[rng <= cfg.max_observation_range_m - cfg.search_radius_max_m]
        return tracked if len(tracked) >= cfg.loss_min_tracked else none

    def _roots(self) -> np.ndarray:
        """(L,) every tree's alias root (itself when not tied to an older copy)."""
        alias = self.aliases()
        return np.where(alias >= 0, alias, np.arange(self.n_landmarks))

    def _vanished(self, tracked: np.ndarray, matches: np.ndarray) -> bool:
        """Whether at most `loss_max_refound` of the tracked trees are among the matches."""
        refound = np.isin(tracked, self._roots()[matches[matches >= 0]]).sum()
        return bool(len(tracked)) and refound <= self.cfg.loss_max_refound * len(tracked)

    def _still_under(self, tracked: np.ndarray, obs_pred: np.ndarray) -> bool:
        """Whether more than `loss_max_refound` of the tracked trees still lie under an
        observation (within `consensus_inlier_m`) at the prediction: the odometry did not jump,
        the consensus moved the scan onto other copies of them (a revisit)."""
        if not len(obs_pred):
            return False
        from scipy.spatial import cKDTree

        d, _ = cKDTree(obs_pred).query(self._lm_xy[tracked])
        return (d <= self.cfg.consensus_inlier_m).sum() > self.cfg.loss_max_refound * len(tracked)

    def _localize(self, obs_map: np.ndarray, matches: np.ndarray) -> np.ndarray:
        """Planar correction (3,3) of a non-keyframe scan from its associated stems: a rigid fit
        of the observed centres onto their trees (>= `scan_align_min_matches` pairs), so scans
        between keyframes (whose stem points build the DBH windows) do not carry the
        odometry's short-term error. Identity when too few pairs or an implausible jump."""
        cfg = self.cfg
        ok = matches >= 0
        if cfg.scan_align_min_matches <= 0 or ok.sum() < cfg.scan_align_min_matches:
            return np.eye(3)
        corr = rigid_2d(obs_map[ok], self._lm_xy[matches[ok]])
        if np.hypot(*corr[:2, 2]) > cfg.search_radius_min_m:
            return np.eye(3)
        return corr

    def _correction(self) -> np.ndarray:
        return pose2_matrix(self._kf_est[-1]) @ np.linalg.inv(pose2_matrix(self._kf_odom2[-1]))

    def _predict(self, o2: np.ndarray) -> np.ndarray:
        """Planar (3,3) map pose predicted from the last keyframe's correction and odometry."""
        return self._correction() @ pose2_matrix(o2)

    def _odometry_noise(self) -> gtsam.noiseModel.Base:
        cfg = self.cfg
        floor_xy = cfg.odom_floor_xy_m + cfg.odom_floor_per_m * self._dist_acc
        floor_yaw = math.radians(cfg.odom_floor_yaw_deg) + cfg.odom_floor_per_m * self._dist_acc
        cov = self._cov_acc + np.diag([floor_xy**2, floor_xy**2, floor_yaw**2])
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        cov = (v * np.clip(w, 1e-10, self.cfg.odom_max_sigma_keyframe**2)) @ v.T
        return gtsam.noiseModel.Gaussian.Covariance(cov)

    def _refinement_factor(self, kf: int, pose: np.ndarray, cov_map: np.ndarray):
        """Between factor from the previous keyframe's estimate to a refined pose (3,3)."""
        prev = pose2_matrix(self._kf_est[-1])
        delta = matrix_pose2(np.linalg.inv(prev) @ pose)
        j = np.eye(3)
        j[:2, :2] = prev[:2, :2].T  # map-frame covariance -> previous keyframe frame
        cov = j @ cov_map @ j.T
        return gtsam.BetweenFactorPose2(
            X(kf - 1),
            X(kf),
            gtsam.Pose2(*delta),
            gtsam.noiseModel.Gaussian.Covariance(0.5 * (cov + cov.T)),
        )

    def _observation_noise(self, rng: np.ndarray) -> list:
        cfg = self.cfg
        sb = np.maximum(math.radians(cfg.bearing_floor_deg), cfg.observation_sigma_m / rng)
        return [(float(b), cfg.observation_sigma_m) for b in sb]

    def _robust(self, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
        kind = self.cfg.robust_kernel.lower()
        if kind == "none":
            return base
        est = gtsam.noiseModel.mEstimator
        m = (
            est.Cauchy.Create(self.cfg.robust_k)
            if kind == "cauchy"
            else est.Huber.Create(self.cfg.robust_k)
        )
        return gtsam.noiseModel.Robust.Create(m, base)

    def _landmark_factor(self, kf: int, lm: int, bearing: float, rng: float, sb, sr):
        noise = self._robust(gtsam.noiseModel.Diagonal.Sigmas(np.array([sb, sr])))
        self.n_landmark_factors += 1
        return gtsam.BearingRangeFactor2D(X(kf), L(lm), gtsam.Rot2.fromAngle(bearing), rng, noise)

    def _add_keyframe(self, o2, obs_s, obs_dbh, obs_z, ids, idx, first: bool) -> int:
        """A keyframe at planar odometry pose o2 (3,) with its stems (levelled sensor frame):
        predict, associate, factors (odometry, refinement, trees), tentative trees, iSAM2."""
        kf = self.n_keyframes
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pred, pose_cov = self._predict_keyframe(o2, first, graph)
        obs_pred = geometry.transform_xy(pred, obs_s)
        res = self._associate(obs_pred, obs_dbh, pose_cov)
        if not first:
            res = self._add_odometry_factor(kf, o2, pred, obs_pred, obs_dbh, res, graph)
        pred = self._refine_keyframe(kf, res.correction @ pred, first, graph)
        obs_map = geometry.transform_xy(pred, obs_s)
        values.insert(X(kf), gtsam.Pose2(*matrix_pose2(pred)))
        bearings = np.arctan2(obs_s[:, 1], obs_s[:, 0])
        ranges = np.linalg.norm(obs_s, axis=1)
        noise = self._observation_noise(ranges)
        matched = res.matches >= 0
        self._kf_lms.append(set(res.matches[matched].tolist()))
        self._add_tree_observations(kf, res.matches, bearings, ranges, noise, obs_dbh, graph)
        ids[idx[matched]] = res.matches[matched]
        self._add_tree_heights(kf, res.matches, obs_z, first)
        if res.support and np.hypot(*res.correction[:2, 2]) > self.cfg.loop_correction_m:
            self.reassociation_corrections += 1
        new_ids = self._update_tentatives(
            kf, obs_map, obs_dbh, obs_z, bearings, ranges, noise, ~matched, graph, values
        )
        for i, lm in new_ids.items():
            ids[idx[i]] = lm
        self._commit_keyframe(kf, o2, graph, values, res)
        self._update_range_offset(kf, res.matches, ranges)
        return kf

    def _predict_keyframe(self, o2: np.ndarray, first: bool, graph) -> tuple:
        """The keyframe's predicted planar map pose (3,3) and its position covariance (2,2);
        the first keyframe is anchored by a tight prior (added to `graph`)."""
        if not first:
            return self._predict(o2), self._pose_cov[:2, :2] + self._cov_acc[:2, :2]
        prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
        graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*o2), prior))
        return pose2_matrix(o2), np.zeros((2, 2))

    def _add_odometry_factor(
        self, kf, o2, pred, obs_pred, obs_dbh, res, graph
    ) -> AssociationResult:
        """The odometry between factor from the previous keyframe. When the trees tracked there
        vanished from the association, either the odometry jumped: a nearly free factor starts
        a new segment, whose trees are then its own (the association is dropped); or, when they
        still lie under the observations at the prediction, the consensus moved the scan onto
        other copies of them, mapped long before (a revisit with metres of drift: the pose
        marginal had grown to 1-2 m, the search radius to its cap). Then the move is declined:
        the chain holds, the scan keeps tracking the recent copies, and the keyframe is left
        in `pending_revisit` for place recognition to verify the old place and tie the copies
        (`tie_trees`), which closes the loop through the unbroken chain. Returns the
        association to use."""
        cfg = self.cfg
        odom_noise = self._odometry_noise()
        tracked = self._tracked_in_range(kf, pred, len(obs_pred))
        vanished = self._vanished(tracked, res.matches)
        if vanished and self._still_under(tracked, obs_pred):
            res = self._associate(obs_pred, obs_dbh, self._cov_acc[:2, :2], False)
            self.pending_revisit, self.revisits = kf, self.revisits + 1
            log.info("keyframe %d: the scan moved onto older copies of its trees", kf)
        elif vanished:
            # a new segment: nearly free of the chain, its trees its own until relocalized
            odom_noise = gtsam.noiseModel.Diagonal.Sigmas(
                np.array([cfg.loss_sigma_m] * 2 + [math.radians(cfg.loss_sigma_deg)])
            )
            res = AssociationResult(matches=np.full(len(obs_pred), -1, dtype=np.int64))
            self.lost_since, self.losses = kf, self.losses + 1
            self._loss_kfs.append(kf)
            log.info("tracking lost at keyframe %d: a new segment starts", kf)
        delta = matrix_pose2(np.linalg.inv(pose2_matrix(self._kf_odom2[-1])) @ pose2_matrix(o2))
        graph.add(gtsam.BetweenFactorPose2(X(kf - 1), X(kf), gtsam.Pose2(*delta), odom_noise))
        return res

    def _refine_keyframe(self, kf: int, pred: np.ndarray, first: bool, graph) -> np.ndarray:
        """The scan-to-map refinement of `refine_hook` (when set): its pose (3,3) replaces the
        prediction and its result is a second between factor."""
        if first or self.refine_hook is None:
            return pred
        refined = self.refine_hook(pred)
        if refined is None:
            return pred
        graph.add(self._refinement_factor(kf, refined[0], refined[1]))
        return refined[0]

    def _add_tree_observations(self, kf, matches, bearings, ranges, noise, obs_dbh, graph):
        """Range-bearing factors to the matched trees; their counts and running-mean DBH."""
        for i in np.nonzero(matches >= 0)[0]:
            lm = int(matches[i])
            graph.add(self._landmark_factor(kf, lm, bearings[i], ranges[i], *noise[i]))
            self._lm_nobs[lm] += 1
            self._lm_run_obs[lm] += 1
            self._lm_last_kf[lm] = kf
            if np.isfinite(obs_dbh[i]):
                n = self._lm_nobs[lm]
                old = self._lm_dbh[lm]
                self._lm_dbh[lm] = (
                    obs_dbh[i] if not np.isfinite(old) else old + (obs_dbh[i] - old) / n
                )

    def _add_tree_heights(self, kf: int, matches, obs_z, first: bool) -> None:
        """The matched trees' observed centre heights (and the height graph's, when on)."""
        matched = matches >= 0
        self._add_heights(matches[matched], obs_z[matched])
        if self.height is not None:
            self.height.add_keyframe(0.0 if first else self._dist_acc)
            for i in np.nonzero(matched)[0]:
                self.height.add_observation(kf, int(matches[i]), obs_z[i])

    def _commit_keyframe(self, kf, o2, graph, values, res: AssociationResult) -> None:
        """iSAM2 update with the keyframe's factors (a failure rebuilds iSAM2 and raises), extra
        relinearizing iterations after a big re-association correction, the new estimate and
        pose marginal; the odometry accumulators restart."""
        self._kf_scan.append(len(self._stamps) - 1)
        self._kf_odom2.append(o2)
        try:
            self.isam.update(graph, values)
        except RuntimeError as exc:  # gtsam's IndeterminateLinearSystemException and kin
            self._rebuild_isam()
            raise ProcessingError(f"pose graph update failed at keyframe {kf}: {exc}") from exc
        self._graph.push_back(graph)
        big = res.support and np.hypot(*res.correction[:2, 2]) > self.cfg.loop_correction_m
        for _ in range(self.cfg.extra_updates_on_loop if big else 0):
            self.isam.update(force_relinearize=True)
        est = self._estimate = self.isam.calculateEstimate()
        self._kf_est = gtsam.utilities.extractPose2(est).reshape(-1, 3)
        if self.n_landmarks:
            self._lm_xy = gtsam.utilities.extractPoint2(est).reshape(-1, 2)
        try:
            self._pose_cov = self._gate_covariance(kf)
        except (RuntimeError, np.linalg.LinAlgError):  # numerically singular: keep the last one
            log.debug("marginal covariance of keyframe %d unavailable", kf)
        self._cov_acc = np.zeros((3, 3))
        self._dist_acc = 0.0

    def _gate_covariance(self, kf: int) -> np.ndarray:
        """(3,3) covariance of keyframe kf that gates the next keyframe's association: its
        marginal while tracking holds. While lost, only the segment's own trees are associated,
        and they sit wherever the segment sits, so what matters is the pose relative to the
        segment, not the loss's wide prior on where the segment is: the marginal conditioned on
        the segment's first keyframe (zero at that keyframe), as if the segment were a new run.
        With the absolute marginal (10 m after a loss) the search radius sat at its cap and the
        gate took any tree within it, so inside the segment the association had no more to go
        on than nearest neighbours."""
        lost = self.lost_since
        if lost is None:
            return self.isam.marginalCovariance(X(kf))
        if kf == lost:
            return np.zeros((3, 3))
        joint = self.isam.jointMarginalCovariance([X(lost), X(kf)]).fullMatrix()
        c11, c12, c22 = joint[:3, :3], joint[:3, 3:], joint[3:, 3:]
        cond = c22 - c12.T @ np.linalg.solve(c11, c12)
        return 0.5 * (cond + cond.T)

    def _update_range_offset(self, kf: int, matches: np.ndarray, ranges: np.ndarray) -> None:
        """Move `range_offset` towards the median range residual (predicted minus observed)
        of this keyframe's observations of trees seen often enough to be placed from several
        sides; bounded by the observation sigma, so it can only remove a small common bias."""
        cfg = self.cfg
        if not cfg.range_offset_gain:
            return
        m = np.flatnonzero(matches >= 0)
        m = m[self._lm_nobs[matches[m]] >= cfg.range_offset_min_observations]
        if len(m) < cfg.consensus_min_support:
            return
        pred = np.linalg.norm(self._lm_xy[matches[m]] - self._kf_est[kf, :2], axis=1)
        step = cfg.range_offset_gain * float(np.median(pred - ranges[m]))
        bound = cfg.observation_sigma_m
        self.range_offset = float(np.clip(self.range_offset + step, -bound, bound))

    def _snapshot(self) -> dict:
        """What adding a keyframe changes before its iSAM2 update (to undo a failed one)."""
        return {
            "lm": {k: v.copy() for k, v in vars(self).items() if k.startswith("_lm_")},
            "tentative": [t.copy() for t in self._tentative],
            "counts": (self.loop_closures, self.reassociation_corrections, self.n_landmark_factors),
            "loss": (self.lost_since, self.losses, self.relocalizations),
            "revisit": (self.pending_revisit, self.revisits),
            "keyframes": self.n_keyframes,
            "height_obs": None if self.height is None else self.height.n_observations,
        }

    def _restore(self, before: dict) -> None:
        for name, value in before["lm"].items():
            setattr(self, name, value)
        self._tentative = before["tentative"]
        self.loop_closures, self.reassociation_corrections, self.n_landmark_factors = before[
            "counts"
        ]
        self.lost_since, self.losses, self.relocalizations = before["loss"]
        self.pending_revisit, self.revisits = before["revisit"]
        self._loss_kfs = [k for k in self._loss_kfs if k < before["keyframes"]]
        n = before["keyframes"]
        del self._kf_scan[n:], self._kf_odom2[n:], self._kf_lms[n:]
        n_lm = len(self._lm_xy)
        for seen in self._kf_lms[-self.cfg.tentative_max_age_keyframes :]:  # failed promotions
            seen.difference_update([lm for lm in seen if lm >= n_lm])
        if self.height is not None:
            self.height.truncate(n, before["height_obs"])

    def _update(self, graph, values, before: dict, what: str) -> None:
        """iSAM2 update with new factors and values; a failure restores `before`, rebuilds
        iSAM2 as it was, counts it and raises ProcessingError."""
        try:
            self.isam.update(graph, values)
        except RuntimeError as exc:  # gtsam's IndeterminateLinearSystemException and kin
            self._restore(before)
            self._rebuild_isam()
            self.failed_updates += 1
            raise ProcessingError(f"pose graph update failed {what}: {exc}") from exc
        self._graph.push_back(graph)

    def _rebuild_isam(self) -> None:
        """A fresh iSAM2 holding the factors and estimate of the last successful update."""
        self.isam = gtsam.ISAM2(self._isam_params)
        if self._graph.size():
            self.isam.update(self._graph, self._estimate)

    def _update_tentatives(
        self, kf, obs_map, obs_dbh, obs_z, bearings, ranges, noise, unmatched, graph, values
    ) -> dict[int, int]:
        """Match unmatched observations to tentative trees; promote those seen often enough."""
        cfg = self.cfg
        self._tentative = [
            t for t in self._tentative if kf - t.last_kf <= cfg.tentative_max_age_keyframes
        ]
        cand = np.nonzero(unmatched)[0]
        if len(cand) and self.n_landmarks:  # too close to a tree: a missed association
            d = np.min(
                np.linalg.norm(obs_map[cand, None, :] - self._lm_xy[None, :, :], axis=2), axis=1
            )
            cand = cand[d >= cfg.min_landmark_separation_m]
        promoted: dict[int, int] = {}
        if len(cand) == 0:
            return promoted
        tent_xy = np.stack([t.xy for t in self._tentative]) if self._tentative else np.zeros((0, 2))
        tent_dbh = (
            np.array(
                [
                    np.nanmedian(t.dbh) if np.isfinite(t.dbh).any() else np.nan
                    for t in self._tentative
                ]
            )
            if self._tentative
            else np.zeros(0)
        )
        assign = np.full(len(cand), -1, dtype=np.int64)
        if len(tent_xy):
            from scipy.optimize import linear_sum_assignment

            dist = np.linalg.norm(obs_map[cand, None, :] - tent_xy[None, :, :], axis=2)
            ok = (dist <= cfg.tentative_gate_m) & dbh_compatible(
                obs_dbh[cand, None], tent_dbh[None, :], cfg.dbh_gate_ratio
            )
            cost = np.where(ok, dist, 1e9)
            r, c = linear_sum_assignment(cost)
            good = cost[r, c] < 1e9
            assign[r[good]] = c[good]
        for row, i in enumerate(cand):
            entry = (kf, float(bearings[i]), float(ranges[i]), *noise[i])
            if assign[row] < 0:
                t = _Tentative(xy=obs_map[i].copy(), last_kf=kf)
                self._tentative.append(t)
            else:
                t = self._tentative[assign[row]]
                n = len(t.obs)
                t.xy = t.xy + (obs_map[i] - t.xy) / (n + 1)
                t.last_kf = kf
            t.obs.append(entry)
            t.dbh.append(float(obs_dbh[i]))
            t.z.append((kf, float(obs_z[i])))
            if len(t.obs) >= cfg.tentative_min_observations:
                promoted[int(i)] = self._promote(t, graph, values)
                t.obs = []  # mark for removal
        self._tentative = [t for t in self._tentative if t.obs]
        return promoted

    def _promote(self, t: _Tentative, graph, values) -> int:
        """A tentative tree seen often enough becomes a landmark: its variable, the factors of
        all its observations, its table entries. Returns its index."""
        lm = self.n_landmarks
        values.insert(L(lm), gtsam.Point2(*t.xy))
        for okf, b, r_, sb, sr in t.obs:
            graph.add(self._landmark_factor(okf, lm, b, r_, sb, sr))
        self._lm_xy = np.vstack([self._lm_xy, t.xy[None, :]])
        self._lm_nobs = np.append(self._lm_nobs, len(t.obs))
        self._lm_run_obs = np.append(self._lm_run_obs, len(t.obs))
        self._lm_last_kf = np.append(self._lm_last_kf, t.last_kf)  # this keyframe
        self._lm_first_kf = np.append(self._lm_first_kf, min(o[0] for o in t.obs))
        zs = np.array([z for _, z in t.z], dtype=np.float64)
        zs = zs[np.isfinite(zs)]
        self._lm_zsum = np.append(self._lm_zsum, zs.sum())
        self._lm_nz = np.append(self._lm_nz, len(zs))
        self._lm_alias = np.append(self._lm_alias, -1)
        self._lm_prior_sigma = np.append(self._lm_prior_sigma, np.nan)
        d = np.asarray(t.dbh)
        self._lm_dbh = np.append(self._lm_dbh, np.nanmedian(d) if np.isfinite(d).any() else np.nan)
        for okf, *_ in t.obs:
            self._kf_lms[okf].add(lm)
        if self.height is not None:
            for okf, z in t.z:
                self.height.add_observation(okf, lm, z)
        return lm
