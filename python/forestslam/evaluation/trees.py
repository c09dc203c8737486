"""Tree-map metrics: Hungarian matching to the truth inside a gate, in a region of interest."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from forestslam.errors import InputError
from forestslam.geometry import transform_points, transform_xy


def _densify(path_xy: np.ndarray, step_m: float) -> np.ndarray:
    """Points along the polyline no more than `step_m` apart (vertices kept)."""
    if len(path_xy) < 2:
        return path_xy
    seg = np.diff(path_xy, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / step_m).astype(np.int64))
    starts = np.repeat(path_xy[:-1], n, axis=0)
    offsets = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    frac = offsets / np.repeat(n, n)
    points = starts + np.repeat(seg, n, axis=0) * frac[:, None]
    return np.vstack([points, path_xy[-1:]])


def distance_to_path(xy: np.ndarray, path_xy: np.ndarray, step_m: float = 0.1) -> np.ndarray:
    """Distance (M,) of points (M,2) to the polyline `path_xy` (P,2), within `step_m`/2."""
    if len(xy) == 0:
        return np.zeros(0)
    if len(path_xy) == 0:
        return np.full(len(xy), np.inf)
    tree = cKDTree(_densify(path_xy, step_m))
    return tree.query(xy)[0]


def _transform_xy(points: np.ndarray, alignment: np.ndarray) -> np.ndarray:
    """(K,2) or (K,3) estimate-frame positions -> (K,2) truth-frame XY by the (4,4) alignment."""
    if points.shape[1] == 3:
        return transform_points(alignment, points)[:, :2]
    return transform_xy(alignment, points)


def _match_one_to_one(
    est: np.ndarray, finite_est: np.ndarray, truth_xy: np.ndarray, gate_m: float
) -> np.ndarray:
    """Matched truth index per estimate (-1: none): the Hungarian method on the XY distances of
    the pairs within gate_m."""
    est_match = np.full(len(est), -1, dtype=np.int64)
    if not (finite_est.any() and len(truth_xy)):
        return est_match
    candidates = cKDTree(truth_xy).query_ball_point(est[finite_est], r=gate_m)
    rows = np.nonzero(finite_est)[0]
    pairs = [(r, c) for r, cs in zip(rows, candidates, strict=True) for c in cs]
    if not pairs:
        return est_match
    pr, pc = np.array(pairs).T
    ur, r_idx = np.unique(pr, return_inverse=True)
    uc, c_idx = np.unique(pc, return_inverse=True)
    big = 1e6
    cost = np.full((len(ur), len(uc)), big)
    cost[r_idx, c_idx] = np.linalg.norm(est[pr] - truth_xy[pc], axis=1)
    ri, ci = linear_sum_assignment(cost)
    ok = cost[ri, ci] <= gate_m
    est_match[ur[ri[ok]]] = uc[ci[ok]]
    return est_match


def tree_errors(
    est_xy: np.ndarray,
    est_dbh: np.ndarray,
    truth_xy: np.ndarray,
    truth_dbh: np.ndarray,
    truth_path_xy: np.ndarray,
    alignment: np.ndarray | None = None,
    gate_m: float = 0.5,
    min_dbh_m: float = 0.1,
    max_dist_m: float = 15.0,
) -> dict:
    """Errors of an estimated tree map against the truth.

    est_xy (K,2) or (K,3) in the estimate frame (with (K,3) the full SE(3) `alignment` is
    applied, with (K,2) its planar part), est_dbh (K,) metres (NaN = unknown); truth_xy (M,2),
    truth_dbh (M,); truth_path_xy (P,2) the true sensor path; alignment (4,4) estimate -> truth
    frame (e.g. `trajectory_errors(...)["alignment"]`), identity when None.

    Matching: one-to-one between all estimated trees and all truth trees (Hungarian method on
    XY distance), pairs farther than `gate_m` discarded.
    Recall: over the *evaluated truth trees*: DBH >= min_dbh_m and within max_dist_m of the
    true path; recall = matched evaluated truth / evaluated truth.
    Precision: over the *evaluated estimates*: estimated trees whose aligned position lies
    within max_dist_m of the true path (the same region of interest); an estimate matched to
    any truth tree (also a thin or just-outside one) is a true positive, so region borders and
    the DBH threshold do not create false positives; precision = matched / evaluated estimates.
    Position and DBH errors (est - truth) over matched evaluated truth trees; DBH statistics
    only where the estimated DBH is finite.
    """
    est_xy = np.asarray(est_xy, dtype=np.float64)
    est_xy = est_xy.reshape(-1, est_xy.shape[-1] if est_xy.ndim == 2 else 2)
    est_dbh = np.asarray(est_dbh, dtype=np.float64).ravel()
    truth_xy = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    truth_dbh = np.asarray(truth_dbh, dtype=np.float64).ravel()
    path = np.asarray(truth_path_xy, dtype=np.float64).reshape(-1, 2)
    if est_xy.shape[1] not in (2, 3):
        raise InputError(f"tree_errors: est_xy must be (K,2) or (K,3), got {est_xy.shape}")
    if len(est_dbh) != len(est_xy) or len(truth_dbh) != len(truth_xy):
        raise InputError("tree_errors: positions and DBH differ in length")
    alignment = np.eye(4) if alignment is None else np.asarray(alignment, dtype=np.float64)

    est = _transform_xy(est_xy, alignment) if len(est_xy) else np.zeros((0, 2))
    finite_est = np.isfinite(est).all(axis=1)
    truth_in_roi = (truth_dbh >= min_dbh_m) & (distance_to_path(truth_xy, path) <= max_dist_m)
    est_in_roi = finite_est & (distance_to_path(est, path) <= max_dist_m)

    est_match = _match_one_to_one(est, finite_est, truth_xy, gate_m)
    matched = est_match >= 0
    truth_matched = np.zeros(len(truth_xy), dtype=bool)
    truth_matched[est_match[matched]] = True
    n_truth = int(truth_in_roi.sum())
    n_est = int(est_in_roi.sum())
    good = matched & truth_in_roi[np.maximum(est_match, 0)]
    e_idx = np.nonzero(good)[0]
    t_idx = est_match[e_idx]
    pos_err = np.linalg.norm(est[e_idx] - truth_xy[t_idx], axis=1)
    dbh_err = est_dbh[e_idx] - truth_dbh[t_idx]
    dbh_err = dbh_err[np.isfinite(dbh_err)]
    nan = float("nan")
    return {
        "recall": float(len(e_idx) / n_truth) if n_truth else nan,
        "precision": float((matched & est_in_roi).sum() / n_est) if n_est else nan,
        "mean_position_error_m": float(pos_err.mean()) if len(pos_err) else nan,
        "dbh_mae_m": float(np.abs(dbh_err).mean()) if len(dbh_err) else nan,
        "dbh_rmse_m": float(np.sqrt(np.mean(dbh_err**2))) if len(dbh_err) else nan,
        "dbh_bias_m": float(dbh_err.mean()) if len(dbh_err) else nan,
        "n_truth": n_truth,
        "n_est": n_est,
        "n_matched": int(len(e_idx)),
        "n_dbh": int(len(dbh_err)),
        "match_est_to_truth": est_match,
    }
