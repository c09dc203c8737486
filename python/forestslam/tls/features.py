"""Per-frame features for MLS-to-TLS registration and stem-based coarse alignment."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from forestslam.geometry import rigid_fit, rot2, yaw_of
from forestslam.tls.bridge import keypoint_config, virtual_feature_config
from forestslam.tls.config import FeatureConfig, RegistrationConfig

log = logging.getLogger(__name__)


def _core():
    from forestslam import _core

    return _core


@dataclass
class FrameFeatures:
    """Features of one frame (its own frame): virtual centres (V,3) with radii (V,), stem
    positions (S,3) with radii (S,), DoG keypoints (K,3) and ground samples (G,3); keypoints
    and ground samples are both real (point-to-plane) features, see real_points."""

    centres: np.ndarray
    radii: np.ndarray
    stems: np.ndarray
    stem_radii: np.ndarray
    keypoints: np.ndarray
    ground: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def real_points(self) -> np.ndarray:
        """(K+G,3) all real features: DoG keypoints then ground samples."""
        return np.ascontiguousarray(np.concatenate([self.keypoints, self.ground]))


def ground_samples(points: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """Evenly spread ground samples (G,3) of a frame: one low point per ground_cell_m x-y cell
    (the median point of its lowest ground_band_m) within ground_max_range_m, kept when it lies
    within ground_max_step_m of the frame's local ground level (the median of the cell samples
    around it: drops cells whose lowest return is a stem, a shrub or the canopy), at most
    ground_max_points of them.
    DoG keypoints hardly ever fall on smooth ground, yet the ground alone fixes the height,
    roll and pitch of a frame (stem centres only fix x, y and heading)."""
    n_max = config.ground_max_points
    if n_max <= 0 or len(points) == 0:
        return np.zeros((0, 3))
    cell = config.ground_cell_m
    rng = np.hypot(points[:, 0], points[:, 1])
    pts = points[(rng <= config.ground_max_range_m) & (rng >= 1.0)]
    if len(pts) == 0:
        return np.zeros((0, 3))
    ij = np.floor(pts[:, :2] / cell).astype(np.int64)
    order = np.lexsort((pts[:, 2], ij[:, 1], ij[:, 0]))
    ij_s, pts_s = ij[order], pts[order]
    start = np.flatnonzero(np.r_[True, np.any(ij_s[1:] != ij_s[:-1], axis=1)])
    # Not the lowest point itself (biased low by the range noise, which would lift the
    # frame) but the median-height point of the cell's lowest ground_band_m.
    zmin = np.repeat(pts_s[start, 2], np.diff(np.r_[start, len(pts_s)]))
    in_band = (pts_s[:, 2] - zmin <= config.ground_band_m).astype(np.int64)
    k = np.add.reduceat(in_band, start)
    low = pts_s[start + (k - 1) // 2]
    if len(low) < 3:
        return np.zeros((0, 3))
    # Local ground level: median of the cell minima within 3 cells; a plane would be better on
    # slopes, but the step gate is loose enough for forest terrain at this scale.
    tree = cKDTree(low[:, :2])
    nb = tree.query(low[:, :2], k=min(9, len(low)))[1]
    level = np.median(low[nb, 2], axis=1)
    low = low[np.abs(low[:, 2] - level) <= config.ground_max_step_m]
    if len(low) > n_max:
        low = low[np.linspace(0, len(low) - 1, n_max).astype(np.int64)]
    return np.ascontiguousarray(low)


def frame_features(
    points: np.ndarray, rings: np.ndarray | None, config: FeatureConfig
) -> FrameFeatures:
    """Virtual features per ring (per horizontal layer when rings is None) and DoG keypoints."""
    core = _core()
    points = np.ascontiguousarray(points, dtype=np.float64)
    ring_list = None if rings is None else np.asarray(rings, dtype=np.uint16)
    vf = core.extract_virtual_features(points, ring_list, virtual_feature_config(config))
    kp = core.detect_dog_keypoints(points, keypoint_config(config)).points
    return FrameFeatures(
        centres=np.asarray(vf.centres).reshape(-1, 3),
        radii=np.asarray(vf.radii, dtype=np.float64),
        stems=np.asarray(vf.stems).reshape(-1, 3),
        stem_radii=np.asarray(vf.stem_radii, dtype=np.float64),
        keypoints=np.asarray(kp).reshape(-1, 3),
        ground=ground_samples(points, config),
    )


def reference_stems(
    points: np.ndarray, config: FeatureConfig, **fit_options
) -> tuple[np.ndarray, np.ndarray]:
    """Stem positions (S,3) and radii (S,) of a TLS / map cloud, from horizontal layers between
    0.5 m and 3.5 m above its lowest ground (cheap, and below most crowns). fit_options: layer
    circle-fit options of extract_virtual_features (e.g. fit_inlier_m, max_fit_rms_m: a map
    merged from noisy mobile frames has thicker stem walls than one TLS scan)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    ground = float(np.percentile(points[:, 2], 1.0))
    band = {"min_z_m": ground + 0.5, "max_z_m": ground + 3.5}
    vf = _core().extract_virtual_features(
        points, None, virtual_feature_config(config, **band, **fit_options)
    )
    return np.asarray(vf.stems).reshape(-1, 3), np.asarray(vf.stem_radii)


def coarse_stem_alignment(
    src_xy: np.ndarray,
    src_r: np.ndarray,
    dst_xy: np.ndarray,
    dst_r: np.ndarray,
    config: RegistrationConfig,
) -> tuple[np.ndarray, int] | None:
    """Planar pose (x, y, yaw) mapping source stems onto destination stems, by voting over
    pairs of stems with matching spacing (and radius) and keeping the pose with most stems
    within coarse_inlier_m; None when fewer than coarse_min_stems agree. Vectorized."""
    found = coarse_stem_hypotheses(src_xy, src_r, dst_xy, dst_r, config, 1)
    return found[0] if found else None


def coarse_stem_hypotheses(
    src_xy: np.ndarray,
    src_r: np.ndarray,
    dst_xy: np.ndarray,
    dst_r: np.ndarray,
    config: RegistrationConfig,
    count: int,
    max_source_stems: int = 15,
) -> list[tuple[np.ndarray, int]]:
    """Up to count distinct planar poses ((x, y, yaw), stems within coarse_inlier_m), best
    first, each with at least coarse_min_stems agreeing stems (see coarse_stem_alignment).
    Poses closer than 1 m and 5 deg to a better one are the same hypothesis."""
    n, m = len(src_xy), len(dst_xy)
    if n < 2 or m < 2:
        return []
    # The nearest source stems suffice and bound the cost.
    order = np.argsort(np.linalg.norm(src_xy, axis=1))[:max_source_stems]
    src_xy, src_r = src_xy[order], src_r[order]
    n = len(src_xy)
    si, sj = np.triu_indices(n, 1)
    ti, tj = np.nonzero(~np.eye(m, dtype=bool))
    ds = np.linalg.norm(src_xy[si] - src_xy[sj], axis=1)
    dt = np.linalg.norm(dst_xy[ti] - dst_xy[tj], axis=1)
    keep_s = ds > 1.0
    si, sj, ds = si[keep_s], sj[keep_s], ds[keep_s]
    order_t = np.argsort(dt)
    dt_sorted = dt[order_t]
    tol = config.coarse_distance_tolerance_m
    lo = np.searchsorted(dt_sorted, ds - tol)
    hi = np.searchsorted(dt_sorted, ds + tol)
    counts = hi - lo
    if counts.sum() == 0:
        return []
    a = np.repeat(np.arange(len(ds)), counts)
    b = order_t[np.concatenate([np.arange(x, y) for x, y in zip(lo, hi, strict=True)])]
    pi, pj, qi, qj = si[a], sj[a], ti[b], tj[b]
    radius_ok = (np.abs(src_r[pi] - dst_r[qi]) < 0.08) & (np.abs(src_r[pj] - dst_r[qj]) < 0.08)
    pi, pj, qi, qj = pi[radius_ok], pj[radius_ok], qi[radius_ok], qj[radius_ok]
    if len(pi) == 0:
        return []
    vs = src_xy[pj] - src_xy[pi]
    vd = dst_xy[qj] - dst_xy[qi]
    # One planar pose (H of them) per pair of matches: the rotation turning the source pair's
    # direction onto the reference pair's, the translation joining their midpoints.
    R = rot2(np.arctan2(vd[:, 1], vd[:, 0]) - np.arctan2(vs[:, 1], vs[:, 0]))
    mid_s = 0.5 * (src_xy[pi] + src_xy[pj])
    t = 0.5 * (dst_xy[qi] + dst_xy[qj]) - np.einsum("hij,hj->hi", R, mid_s)
    # Score every hypothesis on all source stems at once: (H,S) moved positions.
    moved_all = np.einsum("hij,sj->hsi", R, src_xy) + t[:, None, :]
    px, py = moved_all[..., 0], moved_all[..., 1]
    tree = cKDTree(dst_xy)
    dist, _ = tree.query(np.stack([px.ravel(), py.ravel()], axis=1))
    dist = dist.reshape(px.shape)
    inl = dist < config.coarse_inlier_m
    score = inl.sum(axis=1) - np.where(inl, dist, 0.0).sum(axis=1) / config.coarse_inlier_m * 0.5
    out: list[tuple[np.ndarray, int]] = []
    for best in np.argsort(-score, kind="stable")[:300]:  # duplicates of a pose abound
        n_in = int(inl[best].sum())
        if len(out) >= count:
            break
        if n_in < config.coarse_min_stems:
            continue
        # Refine on the inlier pairs.
        moved = np.stack([px[best], py[best]], axis=1)
        _, nn = tree.query(moved)
        mask = inl[best]
        fit = rigid_fit(src_xy[mask], dst_xy[nn[mask]])
        pose = np.array([fit[0, 2], fit[1, 2], yaw_of(fit)])
        if not any(_same_pose(pose, p) for p, _ in out):
            out.append((pose, n_in))
    return out


def _same_pose(a: np.ndarray, b: np.ndarray) -> bool:
    dyaw = abs((a[2] - b[2] + np.pi) % (2 * np.pi) - np.pi)
    return bool(np.hypot(a[0] - b[0], a[1] - b[1]) < 1.0 and dyaw < np.radians(5.0))


def ground_height_near(points: np.ndarray, xy: np.ndarray, radius_m: float = 4.0) -> float | None:
    """Low (5th percentile) height of points within radius_m of xy: the local ground."""
    x, y = np.asarray(xy, dtype=np.float64)
    # The square around xy first (two cheap comparisons per point), the disc within it.
    box = points[(np.abs(points[:, 0] - x) < radius_m) & (np.abs(points[:, 1] - y) < radius_m)]
    d = np.linalg.norm(box[:, :2] - np.array([x, y])[None, :], axis=1)
    near = box[d < radius_m, 2]
    if len(near) < 20:
        return None
    return float(np.percentile(near, 5.0))
