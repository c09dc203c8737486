"""Trajectory metrics: time association, Umeyama SE(3) alignment, ATE, RPE over distance, drift."""

from __future__ import annotations

import numpy as np

from forestslam.errors import InputError


def associate(
    stamps_a: np.ndarray, stamps_b: np.ndarray, max_dt: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one association of two stamp lists by nearest time within `max_dt` seconds.

    Returns index arrays (ia, ib), both (M,), increasing in ia. Each stamp of `a` takes its
    nearest stamp of `b`; when several stamps of `a` claim the same `b`, the closest one keeps it.
    Stamps need not be sorted.
    """
    a = np.asarray(stamps_a, dtype=np.float64).ravel()
    b = np.asarray(stamps_b, dtype=np.float64).ravel()
    empty = np.zeros(0, dtype=np.int64)
    if len(a) == 0 or len(b) == 0:
        return empty, empty.copy()
    order_b = np.argsort(b, kind="stable")
    b_sorted = b[order_b]
    pos = np.searchsorted(b_sorted, a)
    left = np.clip(pos - 1, 0, len(b) - 1)
    right = np.clip(pos, 0, len(b) - 1)
    take_right = np.abs(b_sorted[right] - a) < np.abs(b_sorted[left] - a)
    nearest = np.where(take_right, right, left)
    dt = np.abs(b_sorted[nearest] - a)
    ok = np.isfinite(dt) & (dt <= max_dt)
    ia = np.nonzero(ok)[0]
    ib = order_b[nearest[ok]]
    dt = dt[ok]
    # Keep, for every b claimed more than once, the a closest in time.
    order = np.lexsort((dt, ib))
    first = np.ones(len(order), dtype=bool)
    first[1:] = ib[order][1:] != ib[order][:-1]
    keep = np.sort(order[first])
    return ia[keep].astype(np.int64), ib[keep].astype(np.int64)


def umeyama(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid transform T (4,4) minimising sum ||dst_i - (R src_i + t)||^2 (Umeyama 1991, no scale).

    src, dst: (N,3). N >= 1; with one point (or all points equal) the rotation is the identity;
    for collinear points the rotation about the line is the least-norm one the SVD gives.
    """
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst):
        raise InputError(f"umeyama: {len(src)} source points for {len(dst)} target points")
    if len(src) == 0:
        raise InputError("umeyama: no point pairs to align")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise InputError("umeyama: non-finite coordinates")
    from forestslam.geometry import rigid_fit

    return rigid_fit(src, dst)


def _inverse(poses: np.ndarray) -> np.ndarray:
    inv = np.tile(np.eye(4), (len(poses), 1, 1))
    rt = np.transpose(poses[:, :3, :3], (0, 2, 1))
    inv[:, :3, :3] = rt
    inv[:, :3, 3] = -np.einsum("nij,nj->ni", rt, poses[:, :3, 3])
    return inv


def relative_translation_error(
    est_poses: np.ndarray, gt_poses: np.ndarray, segment_m: float = 10.0
) -> tuple[float, float, int]:
    """KITTI-style relative error over `segment_m` of travelled (true) distance.

    For every start frame i, j is the first frame with path_gt(j) - path_gt(i) >= segment_m;
    E = (gt_i^-1 gt_j)^-1 (est_i^-1 est_j). Returns (mean ||t(E)|| / segment_m * 100 [%],
    mean rotation angle of E per segment [deg], number of segments); NaN when the path is
    shorter than one segment. Independent of any global alignment.
    """
    steps = np.linalg.norm(np.diff(gt_poses[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    j = np.searchsorted(dist, dist + segment_m, side="left")
    i = np.nonzero(j < len(dist))[0]
    if len(i) == 0:
        return float("nan"), float("nan"), 0
    j = j[i]
    rel_gt = np.einsum("nij,njk->nik", _inverse(gt_poses[i]), gt_poses[j])
    rel_est = np.einsum("nij,njk->nik", _inverse(est_poses[i]), est_poses[j])
    err = np.einsum("nij,njk->nik", _inverse(rel_gt), rel_est)
    t_err = np.linalg.norm(err[:, :3, 3], axis=1)
    cos = np.clip((np.trace(err[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    r_err = np.degrees(np.arccos(cos))
    return float(t_err.mean() / segment_m * 100.0), float(r_err.mean()), len(i)


def trajectory_errors(
    est_stamps: np.ndarray,
    est_poses: np.ndarray,
    gt_stamps: np.ndarray,
    gt_poses: np.ndarray,
    max_dt: float = 0.02,
    segment_m: float = 10.0,
) -> dict:
    """Errors of an estimated trajectory against ground truth, both T_world_sensor (N,4,4).

    - ate_rmse_m: RMSE of position residuals after the SE(3) Umeyama alignment of the
      associated estimated positions onto the true ones (`alignment`, (4,4): estimate frame ->
      truth frame); also ate_mean_m, ate_max_m.
    - rpe_percent_10m: mean relative translation error over `segment_m` of true travel, in %
      (KITTI / evo style, see `relative_translation_error`); rpe_deg_10m its rotation part.
    - final_drift_m: position error of the last associated pose when the estimate is anchored
      to the truth at the first associated pose (T = gt_0 est_0^-1), i.e. the accumulated
      drift, not the alignment residual; final_drift_percent divides it by the true path length.
    - n_associated, path_length_m.
    """
    est_stamps = np.asarray(est_stamps, dtype=np.float64).ravel()
    gt_stamps = np.asarray(gt_stamps, dtype=np.float64).ravel()
    est_poses = np.asarray(est_poses, dtype=np.float64).reshape(-1, 4, 4)
    gt_poses = np.asarray(gt_poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(est_stamps) != len(est_poses) or len(gt_stamps) != len(gt_poses):
        raise InputError("trajectory_errors: stamps and poses differ in length")
    ia, ib = associate(est_stamps, gt_stamps, max_dt)
    if len(ia) == 0:
        raise InputError(
            f"trajectory_errors: no estimated stamp is within {max_dt} s of a true stamp"
        )
    est = est_poses[ia]
    gt = gt_poses[ib]
    alignment = umeyama(est[:, :3, 3], gt[:, :3, 3])
    aligned = np.einsum("ij,njk->nik", alignment, est)
    residual = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    rpe, rpe_deg, n_segments = relative_translation_error(est, gt, segment_m)
    anchor = gt[0] @ np.linalg.inv(est[0])
    final = anchor @ est[-1]
    drift = float(np.linalg.norm(final[:3, 3] - gt[-1, :3, 3]))
    path = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
    return {
        "ate_rmse_m": float(np.sqrt(np.mean(residual**2))),
        "ate_mean_m": float(residual.mean()),
        "ate_max_m": float(residual.max()),
        "rpe_percent_10m": rpe,
        "rpe_deg_10m": rpe_deg,
        "rpe_segments": n_segments,
        "final_drift_m": drift,
        "final_drift_percent": drift / path * 100.0 if path > 0 else float("nan"),
        "path_length_m": path,
        "n_associated": int(len(ia)),
        "alignment": alignment,
    }
