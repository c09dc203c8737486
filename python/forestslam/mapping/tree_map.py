"""Tree map: per tree the SLAM position, a DBH fused over windows of accumulated stem points,
its spread and the observation count.

DBH (the paper's 3D mapping): the stem points of the 1.15-1.45 m band above local ground of
every scan that observed the tree are moved into the map frame with the scan's SLAM pose
(keyframes optimised, scans between them aligned onto the tree map) and buffered; once a
window of `dbh_window_scans` scans is full, one robust circle fit gives a DBH measurement with
its quality. The fit knows where every point was seen from (the scan's sensor position,
`forestslam._core.fit_circle_rays`): LiDAR noise lies along the beam, and an orthogonal-distance
fit of the one-sided arcs a window sees shrinks the stem (-2 cm DBH at 3 cm range noise,
bench/dbh_bench.py); the range model does not. Moving past a stem shows it from several
sides, so a window covers much more arc than one scan. A window circle must be physically
possible: an opaque stem hides whatever lies behind its near half, so a circle that points were
seen through (beyond the middle of their beam's chord) is not one stem but a circle through a
clump of stems or a stem and a branch behind it (+68 cm on a tree of a three-stem clump); nor
can it be much wider than the stem's width seen scan by scan (perception's silhouettes).
Pose error between the scans of a window moves their arcs apart and smears the circle: each
block of a few scans is shifted across its beams onto the window circle and the circle refitted
(`align_scans_across`; bench/dbh_pose_replay.py replays a run with SLAM and true poses).
Measurements that pass the gates are fused by a weighted mean (weight: inliers x arc
coverage^2) after dropping outliers beyond 3 MADs of the median.

The DBH itself is the median of perception's per-scan DBH (silhouettes: angular widths, which
neither range noise nor pose error between scans shrink) whenever those scans agree (robust
spread within dbh_fallback_max_spread of the median): over the four 600-scan loops of
bench/dbh_run_trees.py its MAE is 0.51 / 1.20 / 0.22 / 0.45 cm against 1.31 / 2.90 / 0.53 cm for
the window circles, which come out 2-4 cm small on 10-17 cm stems and through clumps several cm
large. Every scan's DBH counts (a bounded buffer thinned evenly over the whole observation,
not the first scans only: those are the far approach views). Its dbh_std_m comes from the data:
the standard error of the median of blocks of dbh_window_scans consecutive scans (scans of one
view share their error; not below that of independent scans), plus dbh_disagreement_share of
the squared difference from the window DBH when the tree has one (an independent measurement:
how far the two disagree shows the systematic error a block spread cannot). When the per-scan
DBHs disagree (a far stem merged with its neighbour in some scans, a clump) the window DBH
decides, its dbh_std_m the standard error of the window mean (Bessel-corrected weighted
spread), the spread of the per-scan DBH and a model floor for sections that are not circles
(dbh_std_floor_rel of the DBH).

Resolution: a silhouette's width is a whole number of azimuth steps, unbiased over scans only
where every scan line keeps its returns. Per-scan DBHs count only from ranges where one step
spans at most 1/2 of the stem (1/3 for stems under dbh_thin_m, whose detection itself depends
on the returns per line), chosen by range, not by the scans' own widths; the stem test's share
of scans with a DBH is counted over those ranges too. A sapling seen only from farther (on the
style-b loops: 2-4 cm stems never nearer than 4-6 m) keeps its position without a DBH: below
the sensor's resolution there, a DBH would be the width of one or two steps, not the stem's.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from forestslam.mapping import thin_stems
from forestslam.mapping.config import MappingConfig
from forestslam.odometry.deskew import deskew_points

log = logging.getLogger(__name__)


# Ranges binned for the resolution gate (TreeMap._resolved_range): 0.25 m up to 40 m.
RANGE_BIN_M = 0.25
N_RANGE_BINS = 160


def _range_bin(rho: float) -> int:
    return min(N_RANGE_BINS - 1, int(rho / RANGE_BIN_M)) if math.isfinite(rho) else N_RANGE_BINS - 1


@dataclass
class _Tree:
    band: list = field(default_factory=list)  # (M,3) arrays, map frame, one per scan
    origins: list = field(default_factory=list)  # (2,) sensor xy each scan's band was seen from
    scan_of: list = field(default_factory=list)  # alignment block of each scan's band
    first_scan: int = -1
    last_scan: int = -1
    n_band_scans: int = 0
    measurements: list = field(default_factory=list)  # (dbh, weight)
    scan_dbh: list = field(default_factory=list)  # per-scan DBH, every scan_stride-th kept
    scan_rho: list = field(default_factory=list)  # the range each kept per-scan DBH was seen at
    # Scans that observed the tree / gave it a per-scan DBH, by range (RANGE_BIN_M bins).
    seen_at: list = field(default_factory=lambda: [0] * N_RANGE_BINS)
    dbh_at: list = field(default_factory=lambda: [0] * N_RANGE_BINS)
    scan_stride: int = 1
    n_scans: int = 0  # scans that observed the tree
    n_scans_dbh: int = 0  # of those, scans with a per-scan DBH
    n_support_scans: int = 0  # of those, scans with stem points in the breast-height band
    z_sum: float = 0.0
    z_n: int = 0
    recent_xy: list = field(default_factory=list)  # the last detections' centres (map frame)
    # accumulated silhouette, per scan: (azimuth step at the stem m, lines not occluded,
    # returns near the centre: is_empty), the sensor's xy, the crossing rings, the kept
    # returns' xy (map frame) and rings (thin_stems.collect_lines)
    sweep: list = field(default_factory=list)
    sweep_origin: list = field(default_factory=list)
    sweep_lines: list = field(default_factory=list)
    sweep_xy: list = field(default_factory=list)
    sweep_ring: list = field(default_factory=list)
    # the sweep's view of the tree, refreshed at every flush: its centre (centre()) and whether
    # it lacks a DBH otherwise, as of n_scans observations
    sweep_centre: np.ndarray | None = None
    sweep_wanted: bool = False
    sweep_checked_at: int = -1

    def centre(self) -> np.ndarray | None:
        """Breast-height centre (3,) in the map frame: median of the last detections' xy, mean
        breast-height z (None before both are known)."""
        if not self.recent_xy or not self.z_n:
            return None
        return np.r_[np.median(np.asarray(self.recent_xy), axis=0), self.z_sum / self.z_n]


def circle_fit_config(cfg: MappingConfig):
    """The C++ CircleFitConfig of the band fits."""
    from forestslam.core_bridge import core_struct

    options = {
        "inlier_threshold_m": cfg.circle_inlier_m,
        "min_radius_m": cfg.dbh_min_m / 2,
        "max_radius_m": cfg.dbh_max_m / 2,
        "lateral_sigma_m": cfg.dbh_lateral_sigma_m,  # used by the range-model fit only
    }
    return core_struct("CircleFitConfig", options, "mapping")


def fit_band_circle(
    xy: np.ndarray, cfg: MappingConfig, origins: np.ndarray | None = None, config=None
):
    """Robust circle fit (forestslam._core.CircleFit) of band points (M,2), under range noise
    along the beams when their view origins (M,2) are given; None when no acceptable fit.
    `config`: circle_fit_config(cfg) when the caller keeps one (else built here)."""
    from forestslam import _core

    if len(xy) < cfg.dbh_min_points:
        return None
    config = circle_fit_config(cfg) if config is None else config
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    if origins is None:
        fit = _core.fit_circle(xy, config)
    else:
        origins = np.ascontiguousarray(origins, dtype=np.float64)
        fit = _core.fit_circle_rays(xy, origins, config)
    if not fit.valid:
        return None
    if fit.inliers < cfg.dbh_min_points or fit.rms_m > cfg.dbh_max_rms_m:
        return None
    if fit.arc_coverage < cfg.dbh_min_arc_coverage:
        return None
    if origins is not None:
        if seen_through_share(xy, origins, fit, cfg.circle_inlier_m) > cfg.dbh_max_seen_through:
            return None
    # Most of the window's points lie on its circle: a window holding two stems (a far stem
    # associated with its neighbour) otherwise gives a circle through both.
    if fit.inliers < cfg.dbh_min_inlier_ratio * len(xy):
        return None
    return fit


def seen_through_share(xy: np.ndarray, origins: np.ndarray, fit, tol_m: float) -> float:
    """Share of the points (M,2) whose beam from its origin (M,2) crosses the fitted circle
    and ends more than tol_m beyond the middle of its chord: points an opaque stem of that
    circle would have hidden (vectorised; an ideal stem view gives 0, range noise alone a few
    per cent at grazing beams)."""
    centre, radius = np.asarray(fit.centre, dtype=np.float64)[:2], float(fit.radius)
    beam = xy - origins
    rng = np.linalg.norm(beam, axis=1)
    ok = rng > 0
    if not ok.all():  # (the copies of a selection only when a point sits at its origin)
        if not ok.any():
            return 0.0
        beam, rng, origins = beam[ok], rng[ok], origins[ok]
    u = beam / rng[:, None]
    to_centre = centre - origins
    mid = np.einsum("ij,ij->i", u, to_centre)  # chord middle along the beam
    miss2 = np.einsum("ij,ij->i", to_centre, to_centre) - mid**2  # beam-centre distance^2
    behind = (miss2 < radius**2) & (rng > mid + tol_m)
    return float(np.count_nonzero(behind)) / len(xy)


def align_scans_across(
    xy: np.ndarray, origins: np.ndarray, scan_of: np.ndarray, fit, cfg: MappingConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Shift each block's band points (M,2) and view origins (M,2) (scan_of (M,): block index)
    across its line of sight onto the window's circle: the pose error between the scans of a
    window moves their arcs sideways and smears the circle. Only the across-beam shift: along
    the beam a shift of every block is a change of radius (no information on it). Per block,
    regularised least squares of the inliers' circle residuals, prior sigma dbh_align_sigma_m
    against the points' dbh_lateral_sigma_m (a block seen head-on, whose points' normals are
    along the beam, is hardly moved)."""
    centre, radius = np.asarray(fit.centre, dtype=np.float64)[:2], float(fit.radius)
    d = xy - centre
    dist = np.linalg.norm(d, axis=1)
    e = dist - radius
    w = (np.abs(e) <= cfg.circle_inlier_m) & (dist > 0)
    normal = d / np.maximum(dist, 1e-12)[:, None]
    view = centre - origins
    view /= np.maximum(np.linalg.norm(view, axis=1), 1e-12)[:, None]
    across = np.column_stack([-view[:, 1], view[:, 0]])
    a = np.einsum("ij,ij->i", normal, across)
    lam = (cfg.dbh_lateral_sigma_m / cfg.dbh_align_sigma_m) ** 2
    n = int(scan_of.max()) + 1
    num = np.bincount(scan_of, weights=w * e * a, minlength=n)
    den = np.bincount(scan_of, weights=w * a * a, minlength=n) + lam
    shift = (-num / den)[scan_of][:, None] * across
    return xy + shift, origins + shift


# Azimuth bins (rad) of the points add_returns selects from (sorted once per scan).
AZ_BIN_RAD = math.radians(0.5)


def _bin_rows(sorted_bins: np.ndarray, centre: float, half: float) -> np.ndarray:
    """Rows of the sorted azimuth bins (of AZ_BIN_RAD from -pi) holding azimuths within half
    of centre (rad; the whole bins, so a little more), across the wrap at +-pi."""
    n = int(np.ceil(2 * np.pi / AZ_BIN_RAD))
    lo = math.floor((centre - half + np.pi) / AZ_BIN_RAD)
    hi = math.floor((centre + half + np.pi) / AZ_BIN_RAD)
    parts = [(max(lo, 0), min(hi, n - 1))]
    if lo < 0:
        parts.append((lo + n, n - 1))
    if hi > n - 1:
        parts.append((0, hi - n))
    rows = [
        np.arange(np.searchsorted(sorted_bins, a), np.searchsorted(sorted_bins, b, "right"))
        for a, b in parts
    ]
    return np.concatenate(rows)


def _spread(d: np.ndarray) -> float:
    """Robust spread (1.4826 MAD) of values d."""
    return float(1.4826 * np.median(np.abs(d - np.median(d))))


class TreeMap:
    """Collects stem observations of mapped trees (ids from the SLAM association)."""

    MAX_SCAN_DBH = 1024  # per tree; beyond, every other value is dropped and the stride doubled
    RECENT_CENTRES = 15  # detections whose median centre places a tree's accumulated silhouette

    def __init__(
        self, config: MappingConfig | None = None, seed: int = 0, azimuth_step_rad: float = 0.0
    ) -> None:
        """`azimuth_step_rad`: the sensor's horizontal resolution, for the resolution gate (0:
        unknown, every scan's DBH counts)."""
        self.cfg = config or MappingConfig()
        self.azimuth_step_rad = float(azimuth_step_rad)
        self.trees: dict[int, _Tree] = {}
        self._rng = np.random.default_rng(seed)
        self.n_fits = 0
        self.n_fits_accepted = 0
        self._circle_config = None  # the C++ CircleFitConfig, built at the first fit
        # Accumulated silhouettes (thin_stems): the trees without a DBH otherwise (updated at
        # every flush), the rings' elevations, the last pose and stamp (deskew).
        self._sweep_ids: list[int] = []
        self._ring_tan: np.ndarray | None = None
        self._last_pose: tuple[float, np.ndarray] | None = None

    def add(
        self,
        scan_index: int,
        T_odom: np.ndarray,
        ids: np.ndarray,
        points: list,
        base_z: np.ndarray,
        centre_z: np.ndarray,
        scan_dbh: np.ndarray,
        ranges: np.ndarray | None = None,
        centre_xy: np.ndarray | None = None,
    ) -> None:
        """Observations of one scan: ids (K,) tree id per stem (-1 none); points[k] (Mk,3) the
        stem's points and base_z (K,) its local ground height, both in the sensor frame;
        centre_z (K,) the breast-height centre z in the map frame; scan_dbh (K,) perception's
        DBH (NaN = none); ranges (K,) the stems' horizontal distance from the sensor (None:
        unknown, no resolution gate); centre_xy (K,2) the breast-height centres in the map
        frame (None: no accumulated silhouette). T_odom (4,4) the (SLAM-corrected) map pose
        of the scan."""
        lo, hi = self.cfg.dbh_band_m
        origin = np.array(T_odom[:2, 3], dtype=np.float64)  # per scan: repeated per point at a fit
        T = np.asarray(T_odom, dtype=np.float64)  # transform_points' R p + t, split once per scan
        R_t, t = T[:3, :3].T, T[:3, 3]
        ids = np.asarray(ids)
        # plain Python values for the per-stem bookkeeping (numpy scalars cost ~1 us per use)
        tree_ids = ids.tolist()
        base_z = np.asarray(base_z, dtype=np.float64)
        base = base_z.tolist()
        centre = np.asarray(centre_z, dtype=np.float64).tolist()
        dbh = np.asarray(scan_dbh, dtype=np.float64).tolist()
        rho = [0.0] * len(ids) if ranges is None else np.asarray(ranges, dtype=np.float64).tolist()
        for k in np.flatnonzero(ids >= 0).tolist():
            tree = self.trees.get(tree_ids[k])
            if tree is None:  # not setdefault: a _Tree per stem costs more than the rest
                tree = self.trees[tree_ids[k]] = _Tree()
            if tree.first_scan < 0:
                tree.first_scan = scan_index
            tree.n_scans += 1
            b = _range_bin(rho[k])
            tree.seen_at[b] += 1
            if math.isfinite(centre[k]):
                tree.z_sum += centre[k]
                tree.z_n += 1
            if centre_xy is not None:
                tree.recent_xy.append(centre_xy[k])
                del tree.recent_xy[: -self.RECENT_CENTRES]
            if math.isfinite(dbh[k]):
                tree.n_scans_dbh += 1
                tree.dbh_at[b] += 1
                self._keep_scan_dbh(tree, dbh[k], rho[k])
            pts = points[k] if k < len(points) else None
            if pts is None or len(pts) == 0 or not math.isfinite(base[k]):
                continue
            h = pts[:, 2] - base_z[k]
            band = pts[(h >= lo) & (h <= hi)]
            if len(band):
                band = np.asarray(band, dtype=np.float64).reshape(-1, 3)
                self._add_band(tree, scan_index, band @ R_t + t, origin)

    def _add_band(self, tree: _Tree, scan_index: int, band: np.ndarray, origin: np.ndarray) -> None:
        """One scan's band points (M,3) of a tree in the map frame, seen from origin (2,); the
        window is fitted once it holds dbh_window_scans scans."""
        tree.n_support_scans += 1
        if tree.n_band_scans == 0:
            tree.first_scan = scan_index
        tree.band.append(band)
        tree.origins.append(origin)
        tree.scan_of.append(tree.n_band_scans // self.cfg.dbh_align_block_scans)
        tree.n_band_scans += 1
        tree.last_scan = scan_index
        if tree.n_band_scans >= self.cfg.dbh_window_scans:
            self._fit(tree)

    def flush(self, scan_index: int | None = None) -> None:
        """Fit the windows of trees out of view for a window (or of all trees when None); then
        list the trees without a DBH otherwise, whose accumulated silhouettes add_returns
        counts."""
        self._flush_windows(scan_index)
        if not self.cfg.dbh_sweep:
            return
        for tree in self.trees.values():
            if tree.n_scans == tree.sweep_checked_at:  # not observed since: same verdict
                continue
            tree.sweep_checked_at = tree.n_scans
            tree.sweep_centre = tree.centre()
            tree.sweep_wanted = tree.sweep_centre is not None and not math.isfinite(
                self._measured_dbh(tree)[0]
            )
        self._sweep_ids = [i for i, tree in self.trees.items() if tree.sweep_wanted]

    def _flush_windows(self, scan_index: int | None) -> None:
        for tree in self.trees.values():
            if not tree.band:
                continue
            stale = scan_index is None or scan_index - tree.last_scan > self.cfg.dbh_window_scans
            if stale:
                if tree.n_band_scans >= self.cfg.dbh_min_window_scans:
                    self._fit(tree)
                else:
                    tree.band, tree.origins, tree.scan_of, tree.n_band_scans = [], [], [], 0

    def _fit(self, tree: _Tree) -> None:
        pts = np.concatenate(tree.band)
        per_scan = [len(b) for b in tree.band]
        origins = np.repeat(np.asarray(tree.origins, dtype=np.float64), per_scan, axis=0)
        scan_of = np.repeat(np.asarray(tree.scan_of, dtype=np.int64), per_scan)
        tree.band, tree.origins, tree.scan_of, tree.n_band_scans = [], [], [], 0
        if len(pts) > self.cfg.dbh_max_points_per_window:
            pick = self._rng.choice(len(pts), self.cfg.dbh_max_points_per_window, False)
            pts, origins, scan_of = pts[pick], origins[pick], scan_of[pick]
        self.n_fits += 1
        xy = pts[:, :2]
        if self._circle_config is None:
            self._circle_config = circle_fit_config(self.cfg)
        fit = fit_band_circle(xy, self.cfg, origins, self._circle_config)
        for _ in range(self.cfg.dbh_align_iterations):
            if fit is None:
                break
            xy, origins = align_scans_across(xy, origins, scan_of, fit, self.cfg)
            fit = fit_band_circle(xy, self.cfg, origins, self._circle_config) or fit
        if fit is None:
            return
        self.n_fits_accepted += 1
        weight = fit.inliers * fit.arc_coverage**2
        tree.measurements.append((2.0 * fit.radius, weight))

    def _keep_scan_dbh(self, tree: _Tree, dbh: float, rho: float) -> None:
        """Keep every scan_stride-th per-scan DBH and its range (tree.n_scans_dbh counts them
        all); a full buffer drops every other value and doubles the stride: bounded memory,
        spread evenly over the whole observation."""
        if (tree.n_scans_dbh - 1) % tree.scan_stride:
            return
        tree.scan_dbh.append(dbh)
        tree.scan_rho.append(rho)
        if len(tree.scan_dbh) >= self.MAX_SCAN_DBH:
            tree.scan_dbh = tree.scan_dbh[::2]
            tree.scan_rho = tree.scan_rho[::2]
            tree.scan_stride *= 2

    def _resolved_range(self, dbh: float) -> float:
        """Farthest range (m) at which one azimuth step spans at most 1 / dbh_resolve_steps
        (dbh_thin_resolve_steps under dbh_thin_m) of a stem of this DBH (inf when the step is
        unknown)."""
        if not (self.azimuth_step_rad > 0):
            return math.inf
        cfg = self.cfg
        steps = cfg.dbh_thin_resolve_steps if dbh < cfg.dbh_thin_m else cfg.dbh_resolve_steps
        return dbh / (steps * self.azimuth_step_rad)

    def _resolved_scans(self, tree: _Tree) -> np.ndarray:
        """The per-scan DBHs of the scans that resolved the stem (module docstring): a
        silhouette needs >= 2 returns on a scan line, so a stem spanning 1-2 azimuth steps
        gives one only when the steps happen to fall twice on it, always 2 steps wide (up to
        2x its DBH); from 2 steps on every line keeps its returns and the width is unbiased.
        Selected by range (not by the scans' own widths, which would select the wide ones):
        ranges where a step spans at most half the DBH (a third for thin stems, see
        MappingConfig.dbh_thin_resolve_steps), the DBH from the scans selected (twice, from the
        median of all)."""
        d = np.asarray(tree.scan_dbh, dtype=np.float64)
        if not (self.azimuth_step_rad > 0) or len(d) == 0:
            return d
        rho = np.asarray(tree.scan_rho, dtype=np.float64)
        keep = d
        for _ in range(2):
            keep = d[rho <= self._resolved_range(float(np.median(keep)))]
            if len(keep) == 0:
                break
        return keep

    def dbh(self, tree_id: int) -> tuple[float, float, int]:
        """Fused DBH, its std and the number of window measurements fused (module docstring);
        for a tree without one, its accumulated silhouette when that measures it (thin_stems,
        0 windows)."""
        tree = self.trees.get(tree_id)
        if tree is None:
            return float("nan"), float("nan"), 0
        measured = self._measured_dbh(tree)
        if math.isfinite(measured[0]) or not self.cfg.dbh_sweep or self.is_empty(tree):
            return measured
        sweep = self.sweep_estimate(tree)
        return (sweep[0], sweep[1], 0) if sweep is not None else measured

    def _measured_dbh(self, tree: _Tree) -> tuple[float, float, int]:
        """The DBH from the per-scan silhouettes and window circles (module docstring)."""
        if not self.is_stem(tree):
            return float("nan"), float("nan"), 0
        scans = self._scan_estimate(tree)
        window = self._window_estimate(tree)
        if scans is not None:
            med, std = scans
            if window is not None:
                share = self.cfg.dbh_disagreement_share
                std = float(np.sqrt(std**2 + share * (med - window[0]) ** 2))
            return med, std, window[2] if window is not None else 0
        if window is not None:
            return window
        return float("nan"), float("nan"), 0

    def window_dbh(self, tree_id: int) -> tuple[float, float, int]:
        """The window circles' DBH alone, its std and the number of windows fused (NaN, NaN, 0
        when none passes): what dbh() falls back to when the per-scan DBHs disagree."""
        tree = self.trees.get(tree_id)
        window = self._window_estimate(tree) if tree is not None else None
        return window if window is not None else (float("nan"), float("nan"), 0)

    def _scan_estimate(self, tree: _Tree) -> tuple[float, float] | None:
        """Median of the per-scan DBH and its std when at least dbh_fallback_min_scans agree
        (robust spread within dbh_fallback_max_spread of the median, or 2 cm), else None. The
        std is the standard error of the median of blocks of dbh_window_scans consecutive
        scans (1.2533 x their robust spread / sqrt(blocks), from 3 blocks on), not below that of
        independent scans. Scans of a far tree merged with its neighbour give 2-4x its DBH:
        better the windows, or none, than that."""
        d = self._resolved_scans(tree)
        if len(d) < self.cfg.dbh_fallback_min_scans:
            return None
        med = float(np.median(d))
        spread = _spread(d)
        if spread > max(0.02, self.cfg.dbh_fallback_max_spread * med):
            return None
        std = 1.2533 * max(spread, 0.005) / np.sqrt(len(d))
        block = max(1, int(np.ceil(self.cfg.dbh_window_scans / tree.scan_stride)))
        if len(d) >= 3 * block:
            blocks = [np.median(d[k : k + block]) for k in range(0, len(d), block)]
            std = max(std, 1.2533 * _spread(np.asarray(blocks)) / np.sqrt(len(blocks)))
        return med, float(std)

    def _window_estimate(self, tree: _Tree) -> tuple[float, float, int] | None:
        """Weighted mean of the window DBHs that pass the gates, its std and their number
        (None when no window passes)."""
        if not tree.measurements:
            return None
        d, w = np.array(tree.measurements).T
        scans = self._resolved_scans(tree)
        if len(scans) >= self.cfg.dbh_fallback_min_scans:
            # A window circle cannot be much wider than the stem seen scan by scan (perception's
            # silhouettes: angular widths, independent of a circle's curvature, and widened,
            # not narrowed, when a scan merges the stem with a neighbour). A circle through a
            # clump, or a stem and a branch behind it, is: +52 and +95 cm on 18 and 13 cm
            # stems that the seen-through gate let pass (vlp16-loop style b).
            agree = d <= self.cfg.dbh_max_scan_ratio * np.median(scans)
            if not agree.any():
                return None
            d, w = d[agree], w[agree]
        if len(d) >= 3:
            med = np.median(d)
            keep = np.abs(d - med) <= max(3 * _spread(d), 0.01)
            d, w = d[keep], w[keep]
        mean = float(np.average(d, weights=w))
        se = np.sqrt(np.average((d - mean) ** 2, weights=w) / (len(d) - 1)) if len(d) > 1 else 0.0
        scan_spread = _spread(scans) if len(scans) >= self.cfg.dbh_fallback_min_scans else 0.0
        floor = self.cfg.dbh_std_floor_rel * mean
        return mean, float(np.sqrt(se**2 + scan_spread**2 + floor**2)), len(d)

    def add_returns(
        self,
        stamp: float,
        T_map_sensor: np.ndarray,
        points: np.ndarray,
        ring: np.ndarray | None,
        times: np.ndarray | None = None,
        T_odom: np.ndarray | None = None,
    ) -> None:
        """Count one scan's lines across the trees without a DBH otherwise (thin_stems): the
        scan's raw points (N,3) in the sensor frame at its stamp, their rings (N,) (None: no
        accumulated silhouette) and times after the stamp (N,) (None: not deskewed);
        T_map_sensor (4,4) the scan's map pose; T_odom (4,4) its odometry pose, whose motion
        from the last scan deskews (smooth; the map poses jump at SLAM corrections; None: the
        map pose)."""
        T = np.asarray(T_map_sensor, dtype=np.float64)
        T_motion = T if T_odom is None else np.asarray(T_odom, dtype=np.float64)
        last, self._last_pose = self._last_pose, (float(stamp), T_motion)
        if not (self.cfg.dbh_sweep and self._sweep_ids and self.azimuth_step_rad > 0):
            return
        if ring is None or len(points) == 0:
            return
        points = np.asarray(points, dtype=np.float64)
        if self._ring_tan is None:
            self._ring_tan = thin_stems.ring_tangents(points, ring)
        cap = self.cfg.dbh_sweep_max_scans
        trees = [self.trees[i] for i in self._sweep_ids if len(self.trees[i].sweep) < cap]
        if not trees:
            return
        # breast-height centres in the sensor frame; those in range
        centres = (np.array([t.sweep_centre for t in trees]) - T[:3, 3]) @ T[:3, :3]
        rho = np.hypot(centres[:, 0], centres[:, 1])
        near = np.flatnonzero((rho > 1.0) & (rho <= self.cfg.dbh_sweep_max_range_m))
        if not len(near):
            return
        pick = self._near_band(points, T, np.array([trees[j].sweep_centre[2] for j in near]))
        bins = np.floor((np.arctan2(points[pick, 1], points[pick, 0]) + np.pi) / AZ_BIN_RAD)
        order = np.argsort(bins.astype(np.int16), kind="stable")  # radix sort
        sorted_bins = bins[order]
        deskew = times is not None and last is not None and stamp > last[0]
        motion = self._motion(last, stamp, T_motion) if deskew else None
        up = T[2, :3]
        cfg = self.cfg
        # raw azimuths a little wider: the sweep moves the sensor up to ~0.3 m and turns it
        turn = abs(motion[5]) * float(np.max(times)) if motion is not None else 0.0
        for j in near.tolist():
            c = centres[j]
            az_c = math.atan2(c[1], c[0])
            half = (thin_stems.REACH_M + 0.1) / rho[j]
            sel = pick[order[_bin_rows(sorted_bins, az_c, half + 0.3 / rho[j] + turn)]]
            pts = points[sel]
            if motion is not None:
                pts = deskew_points(pts, np.asarray(times)[sel], motion)
            inside = np.abs(np.angle(np.exp(1j * (np.arctan2(pts[:, 1], pts[:, 0]) - az_c))))
            keep = inside <= half
            sel, pts = sel[keep], pts[keep]
            crossing, rows, lines, near_centre = thin_stems.collect_lines(
                pts,
                np.asarray(ring)[sel],
                self._ring_tan,
                c,
                up,
                cfg.dbh_sweep_band_m,
                thin_stems.REACH_M,
            )
            if not len(crossing):
                continue
            tree = trees[j]
            tree.sweep.append((rho[j] * self.azimuth_step_rad, lines, near_centre))
            if cfg.dbh_sweep_dbh:  # the returns themselves only for the accumulated DBH
                tree.sweep_origin.append(T[:2, 3].copy())
                tree.sweep_lines.append(crossing)
                tree.sweep_xy.append(pts[rows, :2] @ T[:2, :2].T + T[:2, 3])
                tree.sweep_ring.append(np.asarray(ring)[sel[rows]].astype(np.int64))

    @staticmethod
    def _near_band(points: np.ndarray, T: np.ndarray, breast_z: np.ndarray) -> np.ndarray:
        """Rows of the points (N,3) (sensor frame, pose T) whose map height lies within 1 m of
        the trees' breast heights (map frame): a loose pre-selection, the band itself is taken
        along each ring."""
        z = points @ T[2, :3] + T[2, 3]
        return np.flatnonzero((z >= breast_z.min() - 1.0) & (z <= breast_z.max() + 1.0))

    @staticmethod
    def _motion(last, stamp: float, T: np.ndarray) -> np.ndarray:
        """The planar motion from the last scan's pose to this one's as a body-frame twist (6,)
        per second (v_x, v_y, 0, 0, 0, yaw rate) for the odometry's deskew_points: constant
        velocity over the sweep."""
        d = np.linalg.solve(T, last[1])  # the last pose in this scan's frame
        dt = stamp - last[0]
        yaw_rate = -math.atan2(d[1, 0], d[0, 0]) / dt
        return np.array([-d[0, 3] / dt, -d[1, 3] / dt, 0.0, 0.0, 0.0, yaw_rate])

    def sweep_estimate(self, tree: _Tree) -> tuple[float, float] | None:
        """The accumulated silhouette's DBH and std (MappingConfig.dbh_sweep_*), or None when it
        has too few scans or lines, its hits do not spread across the stem (phases not covered)
        or it is not a thin stem."""
        cfg = self.cfg
        if not cfg.dbh_sweep_dbh or len(tree.sweep) < cfg.dbh_sweep_min_scans:
            return None
        s = np.array([x[0] for x in tree.sweep])
        xy = np.concatenate(tree.sweep_xy)
        if len(xy) < 2:
            return None
        n, k, lat = self._sweep_counts(tree)
        used = n > 0
        if used.sum() < cfg.dbh_sweep_min_scans or n.sum() < cfg.dbh_sweep_min_lines:
            return None
        s, k, n = s[used], k[used], n[used]
        width, se = thin_stems.accumulated_width(s, k, n, cfg.dbh_sweep_block_scans)
        if not (0 < width < cfg.dbh_thin_m) or not (width >= cfg.dbh_sweep_min_sigmas * se):
            return None
        if len(lat) < 2:
            return None
        q10, q90 = np.percentile(lat, [10, 90])
        if (q90 - q10) / 0.8 < cfg.dbh_sweep_min_cover * width:
            return None
        if _spread(lat) > cfg.dbh_sweep_max_spread_m:  # spread over the window: not a stem
            return None
        return width, float(np.hypot(se, cfg.dbh_std_floor_rel * width))

    def _sweep_counts(self, tree: _Tree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lines, net hits per scan and the hits' offsets (thin_stems.net_hits) around the
        stem's centre, found again for every block of dbh_window_scans scans from the centre
        of all: the online poses drift while a far tree is in view (a stem's returns of 20 s
        spread over more than the window otherwise)."""
        cfg = self.cfg
        xy_all = np.concatenate(tree.sweep_xy)
        start = thin_stems.stem_centre(xy_all, tree.centre()[:2], thin_stems.CENTRE_KERNEL_M)
        out = []
        for b in range(0, len(tree.sweep_xy), cfg.dbh_window_scans):
            xy_list = tree.sweep_xy[b : b + cfg.dbh_window_scans]
            xy = np.concatenate(xy_list)
            scan = np.repeat(np.arange(len(xy_list)), [len(h) for h in xy_list])
            centre = thin_stems.stem_centre(xy, start, thin_stems.CENTRE_KERNEL_M)
            out.append(
                thin_stems.net_hits(
                    xy,
                    np.concatenate(tree.sweep_ring[b : b + cfg.dbh_window_scans]),
                    scan,
                    tree.sweep_lines[b : b + cfg.dbh_window_scans],
                    np.asarray(tree.sweep_origin[b : b + cfg.dbh_window_scans]),
                    centre,
                    cfg.dbh_sweep_window_m,
                    cfg.dbh_sweep_depth_m,
                )
            )
        return tuple(np.concatenate([o[i] for o in out]) for i in range(3))

    def is_empty(self, tree: _Tree) -> bool:
        """Nothing at breast height where the tree stands: over at least dbh_sweep_min_lines
        scan lines crossing its breast-height band (accumulated silhouette, not occluded), fewer
        than dbh_empty_max_hits returns per line within thin_stems.EMPTY_REACH_M of its centre. Any
        stem of 2 cm or more gives at least 2 cm / one azimuth step there (0.23 per line for a
        VLP-16 at 25 m, more nearer); a second copy of a stem placed beside it (a split tree)
        or a track of false detections gives none."""
        lines = sum(x[1] for x in tree.sweep)
        if lines < self.cfg.dbh_sweep_min_lines:
            return False
        return sum(x[2] for x in tree.sweep) < self.cfg.dbh_empty_max_hits * lines

    def is_stem(self, tree: _Tree) -> bool:
        """Stem-or-not test of a mapped tree, from the evidence of all its scans: is it a stem
        whose DBH can be measured? (1) Perception found a stem with a diameter in at least half
        of the scans that saw it: a circle or silhouette in only a few of them is chance (two
        stems crossing, foliage; a 56 cm per-scan and a 13 cm window DBH on 3 and 2.5 cm
        saplings seen in 24 and 72 scans). (2) Its 1.15-1.45 m band held stem returns (the
        normal filter's vertical surfaces) in as many scans as one window fit needs
        (dbh_min_window_scans): a shrub, foliage or a sapling inside its crown leaves none there
        while its silhouettes can look like a 40-140 cm stem (vlp16/hdl32 style b: 125-137 cm
        and 39 cm from 0-3 scans with band returns). Silhouettes may stand in for a band
        circle that failed (a thin or far stem), not for a missing band. A tree that fails
        keeps its position (the localizer's evidence) without a DBH."""
        seen, with_dbh = tree.n_scans, tree.n_scans_dbh
        if self.azimuth_step_rad > 0 and tree.scan_dbh:
            # Scans too far to resolve the stem give it no DBH: a sapling seen from 15 m would
            # fail rule (1) in every map. Counted over the ranges that resolve it.
            d = self._resolved_scans(tree)
            far = _range_bin(self._resolved_range(float(np.median(d if len(d) else tree.scan_dbh))))
            seen, with_dbh = sum(tree.seen_at[: far + 1]), sum(tree.dbh_at[: far + 1])
        enough_scans = with_dbh > 0 and 2 * with_dbh >= seen
        return enough_scans and tree.n_support_scans >= self.cfg.dbh_min_window_scans

    def table(self, ids: np.ndarray, xy: np.ndarray, observations: np.ndarray) -> dict:
        """Columns for trees.csv: id,x,y,z,dbh_m,dbh_std_m,observations for the given trees
        (ids (L,), SLAM positions xy (L,2), observation counts (L,)), filtered by
        min_tree_observations. z: mean breast-height centre height in the map frame."""
        ids = np.asarray(ids, dtype=np.int64)
        keep = np.asarray(observations) >= self.cfg.min_tree_observations
        ids, xy, obs = ids[keep], np.asarray(xy)[keep], np.asarray(observations)[keep]
        n = len(ids)
        z = np.full(n, np.nan)
        dbh = np.full(n, np.nan)
        std = np.full(n, np.nan)
        empty = np.zeros(n, dtype=bool)
        for row, i in enumerate(ids):
            tree = self.trees.get(int(i))
            if tree is not None and tree.z_n:
                z[row] = tree.z_sum / tree.z_n
            dbh[row], std[row], _ = self.dbh(int(i))
            empty[row] = tree is not None and not math.isfinite(dbh[row]) and self.is_empty(tree)
        if empty.any():  # nothing at breast height where they stand: not trees (is_empty)
            log.debug("%d mapped trees without returns at breast height left out", empty.sum())
            ids, xy, obs, z, dbh, std = (a[~empty] for a in (ids, xy, obs, z, dbh, std))
            n = len(ids)
        return {
            "id": ids,
            "x": xy[:, 0] if n else np.zeros(0),
            "y": xy[:, 1] if n else np.zeros(0),
            "z": z,
            "dbh_m": dbh,
            "dbh_std_m": std,
            "observations": obs.astype(np.int64),
        }
