"""Data association of observed stems with mapped trees.

Two steps, both vectorised:
1. Consensus shift. Drift since a tree was mapped moves all of its observations the same way,
   so the best planar shift is the one most observations agree on: every observation /
   landmark pair within the search radius (3 sigma of the pose marginal, clamped) proposes a
   shift, each shift is scored by how many observations then land within `consensus_inlier_m`
   of a landmark, and the winner (if it has enough support) is refined to a rigid 2D
   correction by least squares on its inliers. With too little support no correction is made.
2. Gated one-to-one assignment. Each corrected observation / landmark pair gets a squared
   Mahalanobis distance with S = (sigma_obs^2 + sigma_lm^2) I (+ the pose covariance when no
   correction was found); pairs above the chi2 gate, or with incompatible DBH, are excluded and
   the rest assigned by the Hungarian method.
Landmark covariances are approximated from their observation counts (sigma_obs / sqrt(n),
floored) rather than taken from iSAM2 marginals, which would cost one solve per tree.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from forestslam.geometry import rigid_fit, transform_points
from forestslam.slam.config import SlamConfig


@dataclass
class AssociationResult:
    matches: np.ndarray  # (K,) landmark index per observation, -1 = none
    correction: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3,3) planar, map<-pred
    support: int = 0  # observations agreeing with the correction (0 = no correction)


def dbh_compatible(obs_dbh: np.ndarray, lm_dbh: np.ndarray, ratio: float) -> np.ndarray:
    """Elementwise: True when either DBH is unknown or they differ by <= ratio*lm + 5 cm."""
    known = np.isfinite(obs_dbh) & np.isfinite(lm_dbh)
    close = np.abs(obs_dbh - lm_dbh) <= ratio * np.where(np.isfinite(lm_dbh), lm_dbh, 0) + 0.05
    return ~known | close


def _pairs_within(tree: cKDTree, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Every (query, tree point) index pair within `radius` (query_ball_point's lists, flattened
    in their order without an array per list)."""
    cand = tree.query_ball_point(xy, r=radius)
    counts = np.fromiter(map(len, cand), dtype=np.int64, count=len(cand))
    lm_idx = np.fromiter(itertools.chain.from_iterable(cand), dtype=np.int64, count=counts.sum())
    return np.repeat(np.arange(len(cand)), counts), lm_idx


def _consensus(
    obs: np.ndarray, lm_tree: cKDTree, lm_xy: np.ndarray, radius: float, cfg: SlamConfig
) -> tuple[np.ndarray, int]:
    k = len(obs)
    obs_idx, lm_idx = _pairs_within(lm_tree, obs, radius)
    if len(lm_idx) == 0:
        return np.eye(3), 0
    shifts = np.vstack([np.zeros((1, 2)), lm_xy[lm_idx] - obs[obs_idx]])
    moved = (obs[None, :, :] + shifts[:, None, :]).reshape(-1, 2)
    dist, _ = lm_tree.query(moved, distance_upper_bound=cfg.consensus_inlier_m)
    support = np.isfinite(dist).reshape(len(shifts), k).sum(axis=1)
    # best support; ties go to the smallest shift
    order = np.lexsort((np.linalg.norm(shifts, axis=1), -support))
    best = order[0]
    if support[best] < cfg.consensus_min_support:
        return np.eye(3), 0
    corr = np.eye(3)
    corr[:2, 2] = shifts[best]
    n_in = int(support[best])
    for _ in range(3):  # refine to a rigid correction on the inliers
        moved = transform_points(corr, obs)
        dist, nn = lm_tree.query(moved, distance_upper_bound=cfg.consensus_inlier_m)
        inl = np.isfinite(dist)
        if inl.sum() < 2:
            break
        n_in = int(inl.sum())
        corr = rigid_2d(obs[inl], lm_xy[nn[inl]])
    return corr, n_in


def shared_shift(
    src_xy: np.ndarray, dst_xy: np.ndarray, radius: float, cfg: SlamConfig
) -> tuple[np.ndarray, np.ndarray, int]:
    """The consensus of `associate` between two point sets: the rigid correction (3,3) of
    src (K,2) onto dst (L,2) that most src points agree on among the shifts of src / dst pairs
    within `radius`; the pairs (P,2) (src index, dst index) within `consensus_inlier_m` of each
    other after it, one-to-one, nearest first (none below `consensus_min_support`); and the
    number of shifts tried (the hypotheses a chance test must pay for)."""
    none = np.zeros((0, 2), dtype=np.int64)
    if len(src_xy) == 0 or len(dst_xy) == 0:
        return np.eye(3), none, 0
    tree = cKDTree(dst_xy)
    tried = 1 + int(sum(len(c) for c in tree.query_ball_point(src_xy, r=radius)))
    corr, support = _consensus(src_xy, tree, dst_xy, radius, cfg)
    if not support:
        return corr, none, tried
    dist, nn = tree.query(
        transform_points(corr, src_xy), distance_upper_bound=cfg.consensus_inlier_m
    )
    used: set[int] = set()
    pairs = []
    for i in np.argsort(dist):
        if not np.isfinite(dist[i]):
            break
        if int(nn[i]) not in used:
            used.add(int(nn[i]))
            pairs.append((int(i), int(nn[i])))
    return corr, np.array(pairs, dtype=np.int64).reshape(-1, 2), tried


def rigid_2d(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Planar rigid fit (3,3) with dst ~ R src + t of (N,2) pairs (geometry.rigid_fit)."""
    return rigid_fit(src, dst)


def associate(
    obs_xy: np.ndarray,
    obs_dbh: np.ndarray,
    lm_xy: np.ndarray,
    lm_sigma: np.ndarray,
    lm_dbh: np.ndarray,
    pose_cov_xy: np.ndarray,
    cfg: SlamConfig,
    use_consensus: bool = True,
) -> AssociationResult:
    """Associate observations (K,2) in the map frame (predicted pose) with landmarks (L,2).

    obs_dbh (K,), lm_sigma (L,) metres, lm_dbh (L,) (NaN = unknown), pose_cov_xy (2,2) the
    position covariance of the predicted pose. Returns matches (K,) and the planar correction
    applied to the observations before assignment.
    """
    k = len(obs_xy)
    result = AssociationResult(matches=np.full(k, -1, dtype=np.int64))
    if k == 0 or len(lm_xy) == 0:
        return result
    eig = float(np.sqrt(max(np.linalg.eigvalsh(pose_cov_xy).max(), 0.0)))
    radius = float(np.clip(3.0 * eig, cfg.search_radius_min_m, cfg.search_radius_max_m))
    tree = cKDTree(lm_xy)
    if use_consensus and k >= cfg.consensus_min_support:
        result.correction, result.support = _consensus(obs_xy, tree, lm_xy, radius, cfg)
    obs = transform_points(result.correction, obs_xy)
    var_obs = cfg.observation_sigma_m**2
    if result.support:
        pose_var = 0.0  # the correction has absorbed the pose error
        search = max(cfg.search_radius_min_m, 2 * cfg.consensus_inlier_m)
    else:
        pose_var = eig**2
        search = radius
    oi, li = _pairs_within(tree, obs, search)
    if len(li) == 0:
        return result
    e2 = np.sum((obs[oi] - lm_xy[li]) ** 2, axis=1)
    d2 = e2 / (var_obs + lm_sigma[li] ** 2 + pose_var)
    ok = (d2 <= cfg.association_chi2) & dbh_compatible(obs_dbh[oi], lm_dbh[li], cfg.dbh_gate_ratio)
    if not ok.any():
        return result
    oi, li, d2 = oi[ok], li[ok], d2[ok]
    uo, ro = np.unique(oi, return_inverse=True)
    ul, rl = np.unique(li, return_inverse=True)
    big = 1e9
    cost = np.full((len(uo), len(ul)), big)
    cost[ro, rl] = d2
    r, c = linear_sum_assignment(cost)
    good = cost[r, c] < big
    result.matches[uo[r[good]]] = ul[c[good]]
    return result


def duplicate_pairs(
    xy: np.ndarray,
    sigma: np.ndarray,
    dbh: np.ndarray,
    candidates: np.ndarray,
    seen_together,
    config: SlamConfig,
) -> np.ndarray:
    """(P,2) pairs (older, newer) of landmarks among `candidates` (indices into xy (L,2)) that
    look like one tree mapped twice: within the association gate of each other (squared
    Mahalanobis distance with S = (sigma_a^2 + sigma_b^2) I below `association_chi2`),
    compatible DBH, and never observed together (`seen_together(a, b)` False: two trees seen in
    one scan are two trees, however close). Each landmark is in at most one pair, nearest first;
    the older copy is the lower index."""
    candidates = np.asarray(candidates, dtype=np.int64)
    if len(candidates) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    reach = float(np.sqrt(config.association_chi2 * 2.0) * np.max(sigma[candidates]))
    pairs = cKDTree(xy[candidates]).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    a, b = candidates[pairs[:, 0]], candidates[pairs[:, 1]]
    d2 = np.sum((xy[a] - xy[b]) ** 2, axis=1)
    ok = d2 <= config.association_chi2 * (sigma[a] ** 2 + sigma[b] ** 2)
    ok &= dbh_compatible(dbh[a], dbh[b], config.dbh_gate_ratio)
    used: set[int] = set()
    out = []
    for i in np.flatnonzero(ok)[np.argsort(d2[ok])]:
        lo, hi = sorted((int(a[i]), int(b[i])))
        if lo in used or hi in used or seen_together(lo, hi):
            continue
        used.update((lo, hi))
        out.append((lo, hi))
    return np.array(out, dtype=np.int64).reshape(-1, 2)
