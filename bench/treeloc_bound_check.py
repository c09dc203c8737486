"""What the tree tables allow at best (issue 21): an ideal pose graph against the reference.

The SLAM on a tree table can only be as good as the trees' own geometry. This check builds the
best pose graph the trees support, with everything a SLAM must find itself given for free:
- odometry: each frame's trees registered onto those of the frame `lag` before it (the same
  `register_trees` as `tables_slam`), started from the *reference* step, so no drift and no
  failed search; each lag's factors weighted by the spread of its actual errors against the
  reference (the right covariances, measured, not modelled);
- perfect loop closures: every 10th frame that passes within 2 m of a frame at least 200
  frames earlier is tied to it by the reference relative pose (sigma 5 cm);
- a batch Levenberg-Marquardt solution (no incremental-solver or robust-kernel effects).

Printed: the per-lag registration errors (x, y sigma m; yaw sigma deg; and the share of the
lag-1 xy error that a lag-2 registration contradicts, i.e. registration noise rather than
disagreement of the trees with the reference), then planar ATE (SE(2) alignment, as in
treeloc_slam_bench) of the lag-1 chain alone, with perfect closures, with lags 1,2,4,8 and
closures, and with closures but the yaw errors removed (how much of it is heading).

    bench/treeloc_bound_check.py [--session wild_v03] [--lags 1,2,4,8]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from treeloc_slam_bench import DATA, planar_ate

CLOSE_M = 2.0  # a revisit: this close to a frame ...
MIN_GAP = 200  # ... at least this many frames earlier
EVERY = 10  # one closure per this many frames of a revisit
CLOSURE_SIGMA = 0.05


def reference_and_trees(table):
    from forestslam.localization.tables import query_xy
    from forestslam.multisession.tables_slam import level_origin
    from forestslam.slam.landmark_slam import planar, pose2_matrix

    T0_inv = np.linalg.inv(level_origin(table.poses[table.frames[0]]))
    ref = np.stack([pose2_matrix(planar(T0_inv @ table.poses[k])) for k in table.frames])
    trees = [
        query_xy(table, int(k), gravity="reference", max_range_m=20.0)[0] for k in table.frames
    ]
    return ref, trees


def registrations(ref, trees, lag: int) -> dict[int, np.ndarray]:
    """{k: registered planar T_k_k+lag (3,3)}, started from the reference step."""
    from forestslam.multisession.tables_slam import TableOdometryConfig, register_trees

    cfg = TableOdometryConfig()
    out = {}
    for k in range(0, len(ref) - lag, 1 if lag == 1 else 2):
        guess = np.linalg.inv(ref[k]) @ ref[k + lag]
        reg = register_trees(trees[k], trees[k + lag], guess, cfg)
        if reg is not None:
            out[k] = reg[0]
    return out


def step_errors(ref, regs: dict[int, np.ndarray], lag: int) -> np.ndarray:
    """(K,3) x, y, yaw of reference^-1 registration per registered pair."""
    from forestslam.slam.landmark_slam import matrix_pose2

    return np.array(
        [
            matrix_pose2(np.linalg.inv(np.linalg.inv(ref[k]) @ ref[k + lag]) @ m)
            for k, m in regs.items()
        ]
    )


def solve(ref, regs_by_lag: dict, closures: bool, keep_yaw: bool = True) -> float:
    import gtsam

    from forestslam.slam.landmark_slam import matrix_pose2, pose2_matrix

    n = len(ref)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    tight = gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*matrix_pose2(ref[0])), tight))
    for lag, regs in regs_by_lag.items():
        err = step_errors(ref, regs, lag)
        if not keep_yaw:  # the registrations with their heading replaced by the reference's
            regs = {
                k: np.linalg.inv(ref[k]) @ ref[k + lag] @ pose2_matrix(e * [1, 1, 0])
                for (k, _), e in zip(regs.items(), err, strict=True)
            }
            err = err * [1, 1, 0]
        s_xy = float(err[:, :2].std())
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([s_xy, s_xy, max(err[:, 2].std(), 1e-6)]))
        for k, m in regs.items():
            graph.add(gtsam.BetweenFactorPose2(k, k + lag, gtsam.Pose2(*matrix_pose2(m)), noise))
    chain = regs_by_lag[1]
    pose = ref[0].copy()
    values.insert(0, gtsam.Pose2(*matrix_pose2(pose)))
    gap = gtsam.noiseModel.Isotropic.Sigma(3, 0.05)
    for k in range(1, n):
        step = chain.get(k - 1)
        if step is None:  # no registration: the reference step, loosely
            step = np.linalg.inv(ref[k - 1]) @ ref[k]
            graph.add(gtsam.BetweenFactorPose2(k - 1, k, gtsam.Pose2(*matrix_pose2(step)), gap))
        pose = pose @ step
        values.insert(k, gtsam.Pose2(*matrix_pose2(pose)))
    xy = ref[:, :2, 2]
    if closures:
        tie = gtsam.noiseModel.Isotropic.Sigma(3, CLOSURE_SIGMA)
        for i in range(MIN_GAP, n, EVERY):
            d = np.linalg.norm(xy[: i - MIN_GAP] - xy[i], axis=1)
            if len(d) and d.min() < CLOSE_M:
                j = int(d.argmin())
                rel = gtsam.Pose2(*matrix_pose2(np.linalg.inv(ref[j]) @ ref[i]))
                graph.add(gtsam.BetweenFactorPose2(j, i, rel, tie))
    est = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    out = np.array([est.atPose2(k).translation() for k in range(n)])
    return planar_ate(out, xy)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--session", default="wild_v03")
    ap.add_argument("--lags", default="1,2,4,8")
    args = ap.parse_args()
    path = DATA / args.session
    if not path.is_dir():
        print(f"skipped: {path} absent (shared real data not mounted)")
        return 0
    from forestslam.io.tree_tables import read_tree_table

    lags = sorted({1, *(int(v) for v in args.lags.split(","))})
    ref, trees = reference_and_trees(read_tree_table(path))
    regs = {lag: registrations(ref, trees, lag) for lag in lags}
    print(f"{args.session}: {len(ref)} frames; registration errors against the reference")
    for lag in lags:
        e = step_errors(ref, regs[lag], lag)
        print(
            f"  lag {lag}: {len(e)} pairs, sigma x {e[:, 0].std():.4f} y {e[:, 1].std():.4f} m, "
            f"yaw {math.degrees(e[:, 2].std()):.4f} deg"
        )
    if 2 in regs:  # lag-2 registration against the two lag-1 steps it spans
        from forestslam.slam.landmark_slam import matrix_pose2

        d = np.array(
            [
                matrix_pose2(np.linalg.inv(regs[1][k] @ regs[1][k + 1]) @ m)
                for k, m in regs[2].items()
                if k in regs[1] and k + 1 in regs[1]
            ]
        )
        e1 = step_errors(ref, regs[1], 1)
        print(
            "  lag-2 vs two lag-1 steps (registration noise, x sqrt 3 if independent): "
            f"xy {d[:, :2].std():.4f} m (lag-1 error {e1[:, :2].std():.4f}), "
            f"yaw {math.degrees(d[:, 2].std()):.4f} deg ({math.degrees(e1[:, 2].std()):.4f})"
        )
    print("ideal pose graph, planar ATE m:")
    print(f"  lag-1 chain alone                      {solve(ref, {1: regs[1]}, False):.3f}")
    print(f"  lag-1 chain + perfect closures         {solve(ref, {1: regs[1]}, True):.3f}")
    print(
        f"  lags {','.join(map(str, lags))} + perfect closures       {solve(ref, regs, True):.3f}"
    )
    no_yaw = solve(ref, {1: regs[1]}, True, keep_yaw=False)
    print(f"  lag-1 + closures, reference heading    {no_yaw:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
