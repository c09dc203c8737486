"""Stems, DBH and breast-height coverage of a plot cloud (merged map or TLS alone)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from forestslam.tls.config import FeatureConfig, TreeConfig
from forestslam.tls.features import reference_stems

if TYPE_CHECKING:
    from forestslam._core import CircleFit


def _core():
    from forestslam import _core

    return _core


@dataclass
class PlotTrees:
    """K stems: xyz (K,3) breast-height centre, dbh_m (K,) the reported DBH (NaN: its circle
    is not measured well enough, see report_dbh), dbh_std_m (K,) spread of per-slice
    diameters, base_z (K,) ground height, band_points list of (Mi,3), fit_dbh_m (K,) the
    diameter of the fitted breast-height circle (always finite: the stem's extent for
    coverage, observations and drawing), dbh_sigma_m (K,) its 1-sigma from the fit's own
    covariance (2 x the radius standard deviation; NaN: not known), circle_cov (K,3,3) that
    covariance of [centre x, centre y, radius] (inf: no fit), kept so that the fusion with
    the reference does not fit the same band points again. views (P,2) and view_range_m: the
    mobile scanner positions the points were seen from (see plot_trees; None: none), for the
    face test (faced_share). position_measured (K,) bool: the position is a measurement
    (report_dbh: the circle passes the face test and its centre's 1-sigma is within
    TreeConfig.max_position_sigma_m); None: not judged yet. dbh_arc_sigma_m (K,): the 1-sigma
    of the band circle's diameter from what its covariance does not see (arc_sigma: which part
    of the arc is seen, noise wider than the inlier band; inf: too few inliers to tell; NaN:
    not computed, not judged)."""

    xyz: np.ndarray
    dbh_m: np.ndarray
    dbh_std_m: np.ndarray
    base_z: np.ndarray
    band_points: list[np.ndarray]
    fit_dbh_m: np.ndarray | None = None
    dbh_sigma_m: np.ndarray | None = None
    circle_cov: np.ndarray | None = None
    views: np.ndarray | None = None
    view_range_m: tuple[float, float] = (0.0, np.inf)
    position_measured: np.ndarray | None = None
    dbh_arc_sigma_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.fit_dbh_m is None:
            self.fit_dbh_m = np.array(self.dbh_m, dtype=np.float64, copy=True)
        if self.dbh_sigma_m is None:
            self.dbh_sigma_m = np.full(len(self.dbh_m), np.nan)
        if self.circle_cov is None:
            self.circle_cov = np.full((len(self.dbh_m), 3, 3), np.inf)
        if self.dbh_arc_sigma_m is None:
            self.dbh_arc_sigma_m = np.full(len(self.dbh_m), np.nan)

    def __len__(self) -> int:
        return len(self.xyz)


def ground_grid(points: np.ndarray, cell_m: float) -> tuple[cKDTree, np.ndarray]:
    """Per occupied x-y cell the 3rd-lowest height (robust to a stray low return); returns a
    KD-tree over cell centres and their heights."""
    ij = np.floor(points[:, :2] / cell_m).astype(np.int64)
    order = np.lexsort((points[:, 2], ij[:, 1], ij[:, 0]))
    ij_s = ij[order]
    z_s = points[order, 2]
    start = np.flatnonzero(np.r_[True, np.any(ij_s[1:] != ij_s[:-1], axis=1)])
    count = np.diff(np.r_[start, len(order)])
    pick = start + np.minimum(2, count - 1)
    centres = (ij_s[start] + 0.5) * cell_m
    return cKDTree(centres), z_s[pick]


def ground_at(grid: tuple[cKDTree, np.ndarray], xy: np.ndarray, k: int = 9) -> np.ndarray:
    """Ground height at xy (K,2): median of the lowest cells around (stems hide the ground
    right under them)."""
    tree, heights = grid
    k = min(k, len(heights))
    _, idx = tree.query(xy, k=k)
    idx = np.asarray(idx).reshape(len(xy), -1)
    h = np.sort(heights[idx], axis=1)
    return np.median(h[:, : max(1, k // 2 + 1)], axis=1)


def plot_trees(
    points: np.ndarray,
    config: TreeConfig,
    features: FeatureConfig,
    views: np.ndarray | None = None,
    view_range_m: tuple[float, float] = (0.0, np.inf),
    reference: np.ndarray | None = None,
    weights: np.ndarray | None = None,
) -> PlotTrees:
    """Stems from horizontal-layer stem centres, DBH by the robust circle fit on the band
    config.band_m above the local ground (dbh_std_m from four sub-slices). views (P,2): the
    x-y positions the points were scanned from (a mobile walk's trajectory) within
    view_range_m of them: the circle is then fitted under range noise (breast_circle).
    reference (R,3): the TLS cloud the map was merged onto; its own stems join the
    detections (see _stems). weights (N,): per point the number of observations it stands
    for (a voxel map's merge counts, TlsRun.map_counts; None: one each): the circles are
    fitted with each band point counted that often (see _band_fit)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    stems, radii = _stems(points, config, features, reference)
    if len(stems) == 0:
        empty = np.zeros(0)
        return PlotTrees(np.zeros((0, 3)), empty, empty, empty, [], views=views)
    grid = ground_grid(points, config.ground_cell_m)
    base = ground_at(grid, stems[:, :2])
    core = _core()
    lo, hi = config.band_m
    counts = np.ones(len(points), np.int64) if weights is None else _counts(weights, len(points))
    slab = _band_mask(points, base, config.band_m)
    points, counts = points[slab], counts[slab]
    tree2d = cKDTree(points[:, :2])
    xyz, dbh, dbh_std, covs, bases, bands, arcs = [], [], [], [], [], [], []
    for s in range(len(stems)):
        idx = np.asarray(tree2d.query_ball_point(stems[s, :2], radii[s] + 0.15), dtype=np.int64)
        z = points[idx, 2] - base[s]
        idx = canonical_order(points, counts, idx[(z >= lo) & (z <= hi)])
        band, n = points[idx], counts[idx]
        fit = _band_fit(core, band, n, base[s], config, features, views, view_range_m)
        if fit is None:
            continue
        centre, radius, cov, spread, arc = fit
        xyz.append([centre[0], centre[1], base[s] + 0.5 * (lo + hi)])
        dbh.append(2 * radius)
        dbh_std.append(spread)
        covs.append(cov)
        bases.append(base[s])
        bands.append(band)
        arcs.append(arc)
    return PlotTrees(
        xyz=np.array(xyz).reshape(-1, 3),
        dbh_m=np.array(dbh),
        dbh_std_m=np.array(dbh_std),
        base_z=np.array(bases),
        band_points=bands,
        dbh_sigma_m=np.array([_dbh_sigma(c[2, 2]) for c in covs]),
        circle_cov=np.array(covs).reshape(-1, 3, 3),
        views=views,
        view_range_m=view_range_m,
        dbh_arc_sigma_m=np.array(arcs),
    )


def canonical_order(points: np.ndarray, counts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The indices idx (M,) of points (N,3) with counts (N,) sorted by (x, y, z, count): the
    circle fits' RANSAC draws by row, so a stem's circle must not depend on where its points
    sat in the cloud (a voxel map's k-d tree hands them over in an order that changes with
    every merge; on sparse far stems another order gave another DBH)."""
    p = points[idx]
    return idx[np.lexsort((counts[idx], p[:, 2], p[:, 1], p[:, 0]))]


def _counts(weights: np.ndarray, n: int) -> np.ndarray:
    """Per point (n,) its observation count: the weights rounded, at least 1."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != n or not np.all(np.isfinite(w)):
        raise ValueError(f"weights: expected {n} finite values, got {len(w)}")
    return np.maximum(np.rint(w), 1).astype(np.int64)


def _band_fit(
    core,
    band: np.ndarray,
    counts: np.ndarray,
    base_z: float,
    config: TreeConfig,
    features: FeatureConfig,
    views: np.ndarray | None,
    view_range_m: tuple[float, float],
):
    """One stem's breast-height circle from its band points (M,3), each counted counts (M,)
    times -> (centre (2,), radius, covariance (3,3), dbh_std_m) or None.
    Why counts: a voxel map is a union. Each voxel any frame's return fell in holds one
    point, whatever the number of returns, so the more frames are merged, the further the
    tails of the range noise (and every frame's pose error) fill voxels on both sides of a
    stem's wall: a thick ring of evenly spaced points. A robust circle fit with a fixed
    inlier threshold then prefers the outer, longer circles of the ring (spruce-lawn-3m's
    whole walk, 923 frames: band points centred on the true circle within 0.2 cm with a
    10-90 % spread of -4.3 / +5.1 cm, yet the circles 2.2 cm too large in median DBH).
    Counted by the returns behind them, the points are dense at the wall again.
    The counts are the fits' weights (core.fit_circle's weights: a point counts that often,
    the fit of the points repeated). The covariance is the fit's, scaled by the mean count
    (repeated points are not new information); the spread is that of four sub-slices'
    diameters (ddof 1; NaN when fewer than two hold a circle within 5 cm of the band's); the
    last value is arc_sigma of the circle."""
    reps = counts if len(counts) == len(band) else np.ones(len(band), np.int64)
    weights = np.asarray(reps, dtype=np.float64)
    fit = breast_circle(core, band[:, :2], features, views, view_range_m, weights)
    if fit is None:
        return None
    lo, hi = config.band_m
    edges = np.linspace(lo, hi, 5)
    zb = band[:, 2] - base_z
    sub = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        part = (zb >= a) & (zb < b)
        if np.count_nonzero(part) >= 5:
            xy = np.ascontiguousarray(band[part, :2])
            f = core.fit_circle(xy, _circle_config(), weights[part])
            if f.valid and abs(f.radius - fit.radius) < 0.05:
                sub.append(2 * f.radius)
    spread = float(np.std(sub, ddof=1)) if len(sub) >= 2 else float("nan")
    cov = np.asarray(fit.covariance) * (float(np.mean(reps)) if len(reps) else 1.0)
    arc = arc_sigma(core, band[:, :2], weights, fit, config)
    return np.asarray(fit.centre), float(fit.radius), cov, spread, arc


def arc_sigma(core, xy: np.ndarray, weights: np.ndarray, fit, config: TreeConfig) -> float:
    """1-sigma (m) of a diameter fitted to points xy (M,2) with weights (M,) from what the
    fit's covariance does not see; the larger of two estimates. (1) Which part of the arc is
    seen: 2 x the block jackknife of the radius (core.circle_arc_jackknife over
    config.dbh_arc_blocks runs by angle; inf: fewer inliers than 2 per run). A stem is not a
    circle: ovality, polygon faces, lobes and flare bend its arc, so on a partial arc the
    radius depends on which part is seen, and the residuals are not white noise.
    (2) Noise wider than the inlier threshold: the covariance's 1-sigma scaled by the RMS
    residual of all the points the robust fit weighs (within 2.5 x its 2 cm threshold,
    Tukey's window) over that of its inliers. A merged map's far stems are smears of
    centimetre range noise and pose spread; among them a 2 cm inlier band finds a circle of
    nearly any radius, and its inliers' small residuals say nothing of it (spruce-lawn-3m-b:
    an 11.5 cm radius fitted 17.2 cm with a covariance 1-sigma of 0.5 cm, its points 8-17 cm
    from the true centre)."""
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    w = np.ascontiguousarray(weights, dtype=np.float64)
    centre = np.asarray(fit.centre, dtype=np.float64)
    options = _circle_config()
    jackknife = core.circle_arc_jackknife(xy, w, centre, fit.radius, config.dbh_arc_blocks, options)
    e = np.linalg.norm(xy - centre, axis=1) - fit.radius
    near = np.abs(e) <= 2.5 * options.inlier_threshold_m
    rms = np.sqrt(np.sum(w[near] * e[near] ** 2) / max(np.sum(w[near]), 1e-12))
    spread = np.sqrt(max(float(np.asarray(fit.covariance)[2, 2]), 0.0)) * rms / max(fit.rms_m, 1e-4)
    return 2.0 * max(jackknife, spread)


def _stems(
    points: np.ndarray, config: TreeConfig, features: FeatureConfig, reference: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Stem positions (S,3) and radii (S,) of the cloud, plus those of the reference whose
    circle overlaps none of them. A merged map's stem walls carry every merged frame's pose
    error, so over a long walk its layer fits fail the gates on stems the reference alone
    shows clearly; the merged map must not lose them (its DBH is then still measured on the
    merged band, and reported only when good enough, see report_dbh)."""
    options = {"fit_inlier_m": config.stem_fit_inlier_m, "max_fit_rms_m": config.stem_max_fit_rms_m}
    stems, radii = reference_stems(points, features, **options)
    if reference is not None and len(reference):
        stems, radii = _with_reference_stems(stems, radii, reference, features, options)
    order = np.lexsort((stems[:, 1], stems[:, 0]))  # the layer fits list them in point order
    return stems[order], radii[order]


def _with_reference_stems(stems, radii, reference, features, options):
    """_stems' stems (S,3) and radii (S,) plus those of the reference that overlap none."""
    ref_stems, ref_radii = reference_stems(reference, features, **options)
    if len(stems) and len(ref_stems):
        gap = np.linalg.norm(ref_stems[:, None, :2] - stems[None, :, :2], axis=2)
        new = np.all(gap > ref_radii[:, None] + radii[None, :], axis=1)
        ref_stems, ref_radii = ref_stems[new], ref_radii[new]
    return np.vstack([stems, ref_stems]), np.concatenate([radii, ref_radii])


def _dbh_sigma(radius_variance: float) -> float:
    """1-sigma of a diameter from its radius variance (inf when the fit does not know it)."""
    v = float(radius_variance)
    return 2.0 * np.sqrt(v) if np.isfinite(v) and v >= 0 else float("inf")


def _circle_config(features: FeatureConfig | None = None):
    """The circle fit of a stem band: 2 cm inliers, radii within the features' diameter range
    (any radius without `features`)."""
    from forestslam.core_bridge import core_struct

    options = {"inlier_threshold_m": 0.02}
    if features is not None:
        options["min_radius_m"] = 0.5 * features.min_diameter_m
        options["max_radius_m"] = 0.5 * features.max_diameter_m
    return core_struct("CircleFitConfig", options, "tls.features")


def breast_circle(
    core,
    band_xy: np.ndarray,
    features: FeatureConfig,
    views: np.ndarray | None = None,
    view_range_m: tuple[float, float] = (0.0, np.inf),
    weights: np.ndarray | None = None,
) -> CircleFit | None:
    """The robust circle fit (core.fit_circle's CircleFit) of a stem's band points (M,2), or None.
    weights (M,): each point counts that often (None: once).
    With views (P,2), the scanner positions: refined under range noise (fit_circle_rays),
    each point's beam from view_origins. A mobile scanner's noise lies along its beams
    (VLP-16: 3 cm); on the one-sided arcs a walk sees, an orthogonal-distance fit of such
    points shrinks the circle. On the clustered-loop-8m bench plot (56 stems) the merged
    map's band points, and the same frames' raw points placed with the TRUE poses, scatter
    around the true circle (median radial residual -0.05 / +0.09 cm), yet their orthogonal
    fits come out small (median DBH error -1.0 / -1.2 cm); fitted under range noise -0.0 cm
    (map, beams from view_origins) and +0.2 cm (raw points, each from its own scan)."""
    weight = len(band_xy) if weights is None else float(np.sum(weights))
    if weight < 5:
        return None
    xy = np.ascontiguousarray(band_xy, dtype=np.float64)
    config = _circle_config(features)
    fit = core.fit_circle(xy, config, weights)
    if not fit.valid or views is None or len(views) == 0:
        return fit if fit.valid else None
    origins = view_origins(xy, np.asarray(fit.centre), views, view_range_m)
    rays = core.fit_circle_rays(xy, origins, config, weights)
    return rays if rays.valid else fit


def view_origins(
    xy: np.ndarray, centre: np.ndarray, views: np.ndarray, view_range_m: tuple[float, float]
) -> np.ndarray:
    """Per stem point (M,2) a view origin (M,2) for the range-noise fit: the point plus the
    mean offset to the scanner positions views (P,2) that see it (in front of the surface,
    normal from centre, and within view_range_m). A merged map's point is the mean of the
    returns of many frames; its noise lies along their mean beam. A point no position sees
    is given a beam along its normal."""
    views = np.asarray(views, dtype=np.float64).reshape(-1, 2)
    if len(views) > 300:  # the mean direction needs no more than a few hundred positions
        views = views[:: int(np.ceil(len(views) / 300))]
    n = xy - centre
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    off = views[None, :, :] - xy[:, None, :]
    dist = np.linalg.norm(off, axis=2)
    sees = (np.einsum("mk,mpk->mp", n, off) > 0) & (dist >= view_range_m[0])
    sees &= dist <= view_range_m[1]
    count = sees.sum(axis=1)
    mean = np.einsum("mp,mpk->mk", sees, off) / np.maximum(count, 1)[:, None]
    return np.where(count[:, None] > 0, xy + mean, xy + n)


def _circle(core, band_xy: np.ndarray, features: FeatureConfig):
    """[centre x, centre y, radius] (3,) of the robust circle fit of band points (M,2) and its
    covariance (3,3) (CircleFit.covariance: from the inliers), or None without a valid fit."""
    fit = breast_circle(core, band_xy, features)
    if fit is None:
        return None
    x = np.array([*np.asarray(fit.centre), fit.radius])
    cov = np.asarray(fit.covariance)
    return (x, cov) if np.all(np.isfinite(cov)) else None


def _fused(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Two circle estimates (x (3,), covariance (3,3)) fused: the centre information-weighted
    over the full covariances (the other view fixes what a one-sided fit leaves open: the
    centre along the view), the radius by its marginal variances. The mobile points' fits
    shrink without the scanner positions (range noise on one-sided arcs, see breast_circle),
    a bias their covariance does not carry; through the centre-radius correlation the full
    fusion would hand it to the TLS radius too (DBH RMSE higher on 5 of the 7 bench plots).
    Returns x (3,) and its covariance (3,3): the information-fused one, the radius variance
    from the marginal fusion."""
    Ia, Ib = np.linalg.pinv(a[1]), np.linalg.pinv(b[1])
    cov = np.linalg.pinv(Ia + Ib)
    x = cov @ (Ia @ a[0] + Ib @ b[0])
    wa, wb = 1.0 / max(a[1][2, 2], 1e-12), 1.0 / max(b[1][2, 2], 1e-12)
    x[2] = (wa * a[0][2] + wb * b[0][2]) / (wa + wb)
    cov[2, 2] = 1.0 / (wa + wb)
    return x, cov


def fuse_with_reference(
    trees: PlotTrees,
    reference: np.ndarray,
    config: TreeConfig,
    features: FeatureConfig,
    scanners: ReferenceScanners | None = None,
) -> PlotTrees:
    """The merged map's stems with each breast-height circle (centre and DBH) fused with the
    TLS reference's own circle at the same stem, weighted by the inverse covariance of each
    fit (CircleFit.covariance: residual spread and arc geometry; see _fused). A stem the TLS
    saw along a wide arc keeps its TLS circle (the mobile frames' points are noisier and
    carry the registration spread); a stem the TLS saw on a short arc takes the merged
    map's wider one.
    Without a TLS fit the merged circle stands; without a merged fit the TLS one. Then a DBH
    is reported only for a circle measured along enough of its circumference (report_dbh).
    The merged circle is plot_trees' own (under range noise when it was given the walk's
    scanner positions), not fitted again. scanners: where the reference was scanned from
    (None: reference_scanners of the whole reference and config, checked on trees)."""
    reference = np.ascontiguousarray(reference, dtype=np.float64).reshape(-1, 3)
    if scanners is None:
        scanners = reference_scanners(reference, config, trees=trees)
    ref = _band_slab(reference, trees.base_z, config.band_m)
    fused = _fused_circles(trees, ref, config, features)
    return report_dbh(fused, ref, config, features, scanners)


def _fused_circles(
    trees: PlotTrees,
    ref: np.ndarray,
    config: TreeConfig,
    features: FeatureConfig,
) -> PlotTrees:
    """fuse_with_reference's circles, from the reference's points at band heights ref (R,3)."""
    if len(trees) == 0 or len(ref) == 0:
        return trees
    core = _core()
    lo, hi = config.band_m
    tree2d = cKDTree(ref[:, :2])
    xyz, dbh, sigma = trees.xyz.copy(), trees.fit_dbh_m.copy(), trees.dbh_sigma_m.copy()
    covs = trees.circle_cov.copy()
    ones = np.ones(len(ref), np.int64)
    for k in range(len(trees)):
        idx = tree2d.query_ball_point(trees.xyz[k, :2], 0.5 * trees.fit_dbh_m[k] + 0.15)
        near = ref[canonical_order(ref, ones, np.asarray(idx, dtype=np.int64))]
        z = near[:, 2] - trees.base_z[k]
        tls = _circle(core, near[(z >= lo) & (z <= hi), :2], features)
        if tls is None:
            continue
        merged = _band_circle(trees, k)
        if merged is not None and not _same_section(tls, merged):
            continue
        x, covs[k] = tls if merged is None else _fused(tls, merged)
        xyz[k, :2], dbh[k] = x[:2], 2 * x[2]
        sigma[k] = _dbh_sigma(covs[k][2, 2])
    return PlotTrees(
        xyz,
        dbh,
        trees.dbh_std_m,
        trees.base_z,
        trees.band_points,
        None,
        sigma,
        covs,
        trees.views,
        trees.view_range_m,
        dbh_arc_sigma_m=trees.dbh_arc_sigma_m,
    )


def _same_section(a, b) -> bool:
    """Two circle estimates (x = [centre x, centre y, radius], ...) can be the same stem's
    section: each centre lies within the other circle. Around a sapling or a thin stem the
    reference's gathered band holds other returns too, and a circle fitted to them would pull
    the fused centre away (longleaf-loop-12m-b with the rescue on: a 2.2 cm stem moved 11 cm,
    its fused centre 1-sigma 0.1 cm, so counted as measured). Otherwise the merged map's
    circle stands alone."""
    gap = float(np.linalg.norm(a[0][:2] - b[0][:2]))
    return gap <= min(a[0][2], b[0][2])


def _band_circle(trees: PlotTrees, k: int):
    """Stem k's breast-height circle as plot_trees fitted it ([centre x, centre y, radius] (3,),
    covariance (3,3)), or None when its covariance is not known."""
    cov = trees.circle_cov[k]
    if not np.all(np.isfinite(cov)):
        return None
    return np.array([trees.xyz[k, 0], trees.xyz[k, 1], 0.5 * trees.fit_dbh_m[k]]), cov


def report_dbh(
    trees: PlotTrees,
    reference: np.ndarray,
    config: TreeConfig,
    features: FeatureConfig | None = None,
    scanners: ReferenceScanners | None = None,
) -> PlotTrees:
    """The stems with a DBH reported only where their breast-height circle is measured: the
    diameter is resolved (diameter_resolved: the fit's covariance and the agreement of
    sub-slices, a 1-sigma of at most config.max_dbh_sigma_m) and its points (the map's band
    and the reference's) cover at least config.min_dbh_coverage of the circumference
    (coverage_tolerance_m of the circle).
    A few sparse points with range noise as large as the radius (a far stem's 30-40 points, a
    sapling's noise smear) can be fitted by circles of very different radii: the covariance
    says so, the coverage may not. On a shorter arc the radius and the centre along the view
    trade off (the fit's covariance grows without bound) and the fit follows the noise: on the
    7 generated bench plots, stems seen on less than a quarter of their circumference were off
    by up to 14 cm (a 2 cm sapling fitted 12 cm, edge stems 30 m out with one-sided points).
    Such a stem keeps its position; its dbh_m is NaN, its fitted circle stays in fit_dbh_m.
    A circle that is not a face seen from outside (faced_share below config.min_faced_share)
    gives no DBH and no measured position; nor does a centre whose 1-sigma exceeds
    config.max_position_sigma_m (position_measured False; the position is still reported).
    scanners: where the reference was scanned from (None: reference_scanners of reference
    and config, without the check on the stems' points; pass them when reference is not the
    whole reference cloud: fuse_with_reference and the runner resolve them over all stems)."""
    if len(trees) == 0:
        return trees
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if scanners is None:  # not checked on these stems' points: a bent circle would fail it
        scanners = reference_scanners(reference, config)
    points = np.concatenate([np.vstack(trees.band_points), reference])
    cover = circumference_coverage(points, trees, config)
    faced = faced_shares(trees, config, scanners.xy) >= config.min_faced_share
    resolved = diameter_resolved(trees, config, features) & faced
    dbh = np.where((cover >= config.min_dbh_coverage) & resolved, trees.fit_dbh_m, np.nan)
    return PlotTrees(
        trees.xyz,
        dbh,
        trees.dbh_std_m,
        trees.base_z,
        trees.band_points,
        trees.fit_dbh_m,
        trees.dbh_sigma_m,
        trees.circle_cov,
        trees.views,
        trees.view_range_m,
        faced & (position_sigma(trees) <= config.max_position_sigma_m),
        trees.dbh_arc_sigma_m,
    )


def position_sigma(trees: PlotTrees) -> np.ndarray:
    """Per stem (K,) the 1-sigma of its breast-height centre along its worst direction (the
    largest eigenvalue of the circle covariance's centre block; inf: not known)."""
    centre = np.asarray(trees.circle_cov, dtype=np.float64)[:, :2, :2]
    out = np.full(len(centre), np.inf)
    ok = np.all(np.isfinite(centre), axis=(1, 2))
    if np.any(ok):
        out[ok] = np.sqrt(np.maximum(np.linalg.eigvalsh(centre[ok])[:, -1], 0.0))
    return out


@dataclass(frozen=True)
class ReferenceScanners:
    """Where the reference was scanned from, as the face test uses it: xy (S,2) in the
    reference's frame (the frame of the trees; empty: not known) and source, why (for the
    log and run.yaml)."""

    xy: np.ndarray
    source: str


def reference_scanners(
    reference: np.ndarray,
    config: TreeConfig,
    viewpoint: np.ndarray | None = None,
    trees: PlotTrees | None = None,
    file_origin_xy: np.ndarray | None = None,
) -> ReferenceScanners:
    """config.reference_scanners_xy resolved for the reference (R,3): a list as given; "auto":
    the file's scanner position viewpoint (x, y[, z]) when the reader has one, else the
    origin when it lies inside the reference's xy extent (a single scan is stored in its
    scanner's frame and surrounds it), else none; with trees, such a position is kept only
    when the reference's points on their breast-height circles face it (at least
    config.min_reference_faced_share of them: a single scan from there; a registered
    multi-scan plot stored in one station's frame is not). A wrong position would make the
    points the reference saw on the far sides of stems fail the face test (their stems
    silently lose their DBH); an unknown one only leaves the reference's points unjudged.
    The configured positions, viewpoint and origin are the reference file's; file_origin_xy:
    where that file's origin lies in the frame `reference` is given in (tls.frame: minus the
    local frame's offset; default the same frame). Returned positions are in that frame."""
    origin = np.zeros(2) if file_origin_xy is None else np.asarray(file_origin_xy, np.float64)
    setting = config.reference_scanners_xy
    if setting != "auto":
        xy = np.asarray(setting, dtype=np.float64).reshape(-1, 2) + origin
        return ReferenceScanners(xy, "configured" if len(xy) else "none: configured empty")
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if viewpoint is not None:
        xy = np.asarray(viewpoint, dtype=np.float64).reshape(-1)[:2].reshape(1, 2) + origin
        source = "auto: the reference file's scanner position (viewpoint)"
    elif _inside_extent(reference[:, :2], origin):
        xy, source = origin.reshape(1, 2), "auto: the reference frame's origin, inside its extent"
    else:
        extent = _extent_text(reference[:, :2], origin) if len(reference) else "empty"
        return ReferenceScanners(
            np.zeros((0, 2)),
            f"auto: none known (the origin lies outside the reference's extent, {extent}: not "
            "a single scan in its scanner's frame; set tls.trees.reference_scanners_xy if known)",
        )
    share = None if trees is None else reference_faced_share(reference, trees, xy, config)
    if share is not None and share < config.min_reference_faced_share:
        where = (xy[0] - origin).tolist()  # the file's frame
        return ReferenceScanners(
            np.zeros((0, 2)),
            f"auto: none known ({source[6:]} {where} faces only {100 * share:.0f} % of "
            "the reference's stem points: not a single scan from there, e.g. a registered "
            "multi-scan plot; set tls.trees.reference_scanners_xy to its stations if known)",
        )
    faces = "" if share is None else f"; faces {100 * share:.1f} % of the reference's stem points"
    return ReferenceScanners(xy, source + faces)


def reference_faced_share(
    reference: np.ndarray, trees: PlotTrees, xy: np.ndarray, config: TreeConfig
) -> float | None:
    """Share of the reference's points (R,3) on the stems' breast-height circles (at band
    height, within coverage_tolerance_m) that face a station in xy (S,2) (see faced_share);
    None: no such point."""
    ref = _band_slab(np.asarray(reference, dtype=np.float64), trees.base_z, config.band_m)
    if len(ref) == 0 or len(trees) == 0:
        return None
    tree2d, tol = cKDTree(ref[:, :2]), config.coverage_tolerance_m
    faced = total = 0.0
    for k in range(len(trees)):
        r, c = 0.5 * trees.fit_dbh_m[k], trees.xyz[k, :2]
        p = ref[tree2d.query_ball_point(c, r + tol)]
        z = p[:, 2] - trees.base_z[k]
        p = p[(z >= config.band_m[0]) & (z <= config.band_m[1])]
        n = int(np.sum(np.abs(np.linalg.norm(p[:, :2] - c, axis=1) - r) <= tol))
        if n:
            faced += n * faced_share(p[:, :2], c, r, [(xy, (0.0, np.inf))], tol)
            total += n
    return faced / total if total else None


def _inside_extent(xy: np.ndarray, point: np.ndarray) -> bool:
    """The point (2,) lies within the xy extent (bounding box) of the points (N,2)."""
    if len(xy) == 0:
        return False
    lo, hi = _extent(xy)
    return bool(np.all(lo <= point) and np.all(hi >= point))


def _extent(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis min and max (2,) of the points (N,2), column by column (numpy's axis-0
    reduction of a narrow (N,2) array costs 10x more: 220 ms for 4 M points)."""
    lo = np.array([xy[:, k].min() for k in range(xy.shape[1])])
    return lo, np.array([xy[:, k].max() for k in range(xy.shape[1])])


def _extent_text(xy: np.ndarray, origin: np.ndarray) -> str:
    """The xy extent of the points (N,2) relative to origin (2,) (in the file's frame)."""
    lo, hi = _extent(xy)
    lo, hi = lo - origin, hi - origin
    return f"x {lo[0]:.1f}..{hi[0]:.1f}, y {lo[1]:.1f}..{hi[1]:.1f}"


def faced_shares(trees: PlotTrees, config: TreeConfig, stations: np.ndarray) -> np.ndarray:
    """Per stem (K,) faced_share of its circle over its band points, the scanners being the
    walk's positions (trees.views within trees.view_range_m) and the reference's stations
    (S,2) (reference_scanners, any range)."""
    stations = np.asarray(stations, dtype=np.float64).reshape(-1, 2)
    views = np.zeros((0, 2)) if trees.views is None else np.asarray(trees.views).reshape(-1, 2)
    out = np.ones(len(trees))
    for k in range(len(trees)):
        out[k] = faced_share(
            trees.band_points[k][:, :2],
            trees.xyz[k, :2],
            0.5 * trees.fit_dbh_m[k],
            [(views, trees.view_range_m), (stations, (0.0, np.inf))],
            config.coverage_tolerance_m,
        )
    return out


def faced_share(
    xy: np.ndarray,
    centre: np.ndarray,
    radius: float,
    scanners: list[tuple[np.ndarray, tuple[float, float]]],
    tolerance_m: float,
) -> float:
    """Share of the circle's inliers (points xy (M,2) within tolerance_m of it) whose outward
    normal (from centre) points towards at least one scanner that can see them: scanners is
    a list of (positions (P,2), range (min, max)). A scanner sees a stem's near face only, so
    the points of a true circle face their scanners; a circle fitted on a noise blob whose
    centre lies on the scanners' side of the points faces them with about half its inliers,
    or none. No inlier or no scanner: 1 (nothing to judge)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy - np.asarray(centre, dtype=np.float64)
    d = np.linalg.norm(n, axis=1)
    inl = np.abs(d - radius) <= tolerance_m
    n, xy = n[inl] / np.maximum(d[inl], 1e-12)[:, None], xy[inl]
    if len(xy) == 0 or sum(len(p) for p, _ in scanners) == 0:
        return 1.0
    faces = np.zeros(len(xy), dtype=bool)
    for positions, (lo, hi) in scanners:
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        if len(positions) > 300:  # the directions need no more than a few hundred positions
            positions = positions[:: int(np.ceil(len(positions) / 300))]
        off = positions[None, :, :] - xy[:, None, :]
        dist = np.linalg.norm(off, axis=2)
        sees = (np.einsum("mk,mpk->mp", n, off) > 0) & (dist >= lo) & (dist <= hi)
        faces |= sees.any(axis=1)
    return float(np.mean(faces))


def diameter_resolved(
    trees: PlotTrees, config: TreeConfig, features: FeatureConfig | None = None
) -> np.ndarray:
    """Per stem (K,) bool: both estimates of its diameter's 1-sigma are at most
    config.max_dbh_sigma_m and (with features) the diameter stands clear of the circle fit's
    lower bound (features.min_diameter_m) by that precision: a circle fitted at the bound is
    held there by the bound, not by the points (a 2 cm sapling's noise smear fits the
    smallest circle allowed, or one a little larger). The two estimates of the 1-sigma:
    (1) the fit's covariance (dbh_sigma_m; NaN: not computed, not judged). It comes from
    the inliers within the fit's 2 cm threshold, so on sparse points with centimetre noise
    it is optimistic (25 band points with 2 cm noise: sigma 0.8 cm for a diameter 5 cm
    off). (2) The spread of the four sub-slice diameters (dbh_std_m) over
    sqrt(4): independent points of the same section must agree; fewer than two sub-slices
    that hold a circle (NaN) do not resolve it. (3) What the covariance does not see
    (dbh_arc_sigma_m, see arc_sigma: which part of the arc is seen, and noise wider than the
    fit's inlier band; inf: too few points to tell, not resolved; NaN: not computed, not
    judged)."""
    sub = trees.dbh_std_m / 2.0
    cov_ok = ~(trees.dbh_sigma_m > config.max_dbh_sigma_m)
    ok = cov_ok & np.isfinite(sub) & (sub <= config.max_dbh_sigma_m)
    ok &= ~(np.asarray(trees.dbh_arc_sigma_m) > config.max_dbh_sigma_m)
    if features is not None:
        ok &= trees.fit_dbh_m >= features.min_diameter_m + config.max_dbh_sigma_m
    return ok


def _band_slab(points: np.ndarray, base_z: np.ndarray, band_m) -> np.ndarray:
    """The points (M,3) at heights any stem's breast-height band can reach (between the
    lowest base plus band_m[0] and the highest base plus band_m[1]): the spatial index is
    built over this slab, not the whole plot cloud (crowns and ground are most of it)."""
    return points[_band_mask(points, base_z, band_m)]


def _band_mask(points: np.ndarray, base_z: np.ndarray, band_m) -> np.ndarray:
    """Which points (N,) lie in _band_slab's slab."""
    if len(base_z) == 0:
        return np.zeros(len(points), bool)
    z = points[:, 2]
    return (z >= np.min(base_z) + band_m[0]) & (z <= np.max(base_z) + band_m[1])


def circumference_coverage(points: np.ndarray, trees: PlotTrees, config: TreeConfig) -> np.ndarray:
    """Share (K,) of each stem's circumference at breast height holding points of `points`:
    occupied angular sectors within coverage_tolerance_m of the fitted circle."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(trees))
    if len(points) == 0 or len(trees) == 0:
        return out
    lo, hi = config.band_m
    points = _band_slab(points, trees.base_z, config.band_m)
    if len(points) == 0:
        return out
    tree2d = cKDTree(points[:, :2])
    n = config.coverage_sectors
    for k in range(len(trees)):
        r = 0.5 * trees.fit_dbh_m[k]
        c = trees.xyz[k, :2]
        idx = tree2d.query_ball_point(c, r + config.coverage_tolerance_m)
        p = points[idx]
        z = p[:, 2] - trees.base_z[k]
        d = np.linalg.norm(p[:, :2] - c, axis=1)
        on = (z >= lo) & (z <= hi) & (np.abs(d - r) <= config.coverage_tolerance_m)
        ang = np.arctan2(p[on, 1] - c[1], p[on, 0] - c[0])
        sectors = np.unique(np.floor((ang + np.pi) / (2 * np.pi) * n).astype(int) % n)
        out[k] = len(sectors) / n
    return out


def observations(
    trees: PlotTrees,
    frame_centres: list[np.ndarray],
    reference_sees: np.ndarray,
    radius_margin_m: float = 0.1,
) -> np.ndarray:
    """Per stem: number of scans that saw it (TLS reference when reference_sees, plus each
    accepted MLS frame with a registered stem centre on it)."""
    counts = reference_sees.astype(np.int64).copy()
    if len(trees) == 0:
        return counts
    tree2d = cKDTree(trees.xyz[:, :2])
    for centres in frame_centres:
        if len(centres) == 0:
            continue
        d, idx = tree2d.query(centres[:, :2])
        hit = idx[d <= 0.5 * trees.fit_dbh_m[idx] + radius_margin_m]
        counts[np.unique(hit)] += 1
    return counts
