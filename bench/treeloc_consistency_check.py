"""Do the reference poses and the tree tables form one consistent map? (issue 21)

Every frame's trees are placed in the world by the reference pose (full 3D rotation, so exactly
the levelling `tables_slam` uses) and compared:

1. along the route: frame k against frame k + lag, and at revisits (a frame >= 200 frames
   earlier within 3 m): matched trees' median distance and the rigid (yaw, centroid shift) fit
   between the two placements. Opposite-direction revisits also measure a time-stamp / frame
   offset or lever arm between the tables and the poses: it would show as a mean along-track
   shift (twice the offset);
2. the levelling: the angle between each frame's median stem axis, rotated by the reference,
   and the world vertical (a wrong roll / pitch or axis convention shows here);
3. radial consistency: each tree's placement minus the mean of its cluster, along the ray from
   the observing pose, regressed on the range (a local map shrunk about its pose gives a slope
   of -shrinkage);
4. the landmark-graph bound: keyframes every 5 m, landmarks = the reference-placed clusters
   (perfect association), range-bearing factors (sigma 3 cm + 0.4 % of range, Huber), nearly
   free odometry, batch Levenberg-Marquardt started at the reference. Planar ATE with SE(2)
   alignment (as the SLAM bench) and with Sim(2) alignment (its scale printed): what a landmark
   SLAM can reach with the trees' own metric.

    bench/treeloc_consistency_check.py [--session wild_v03]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from treeloc_slam_bench import DATA, planar_ate, sim2_ate

RANGE_M = 20.0
REVISIT_M, REVISIT_GAP = 3.0, 200
MATCH_M = 0.3


def world_trees(table) -> list[np.ndarray]:
    """Per frame (K,2): the trees within RANGE_M, levelled by the reference gravity as the SLAM
    bench does, placed by the reference pose (the same as the 3D placement, projected)."""
    from forestslam.localization.tables import query_xy

    out = []
    for k in table.frames:
        xy, _ = query_xy(table, int(k), gravity="reference", max_range_m=RANGE_M)
        T = table.poses[k]
        y = heading(T)
        R = np.array([[math.cos(y), -math.sin(y)], [math.sin(y), math.cos(y)]])
        out.append(xy @ R.T + T[:2, 3])
    return out


def heading(T: np.ndarray) -> float:
    return math.atan2(T[1, 0], T[0, 0])


def compare(table, W, j: int, k: int):
    """(matches, median distance, shift in frame k's heading (2,), yaw deg, heading change deg)
    of frame k's placed trees fitted onto frame j's; None with fewer than 8 matches."""
    from forestslam.geometry import rigid_fit

    a, b = W[j], W[k]
    d, i = cKDTree(a).query(b, distance_upper_bound=1.0)
    ok = d < MATCH_M
    if ok.sum() < 8:
        return None
    c = a[i[ok]].mean(axis=0)
    T = rigid_fit(b[ok] - c, a[i[ok]] - c)
    y = heading(table.poses[table.frames[k]])
    R = np.array([[math.cos(y), -math.sin(y)], [math.sin(y), math.cos(y)]])
    dh = math.degrees(y - heading(table.poses[table.frames[j]]))
    return (
        int(ok.sum()),
        float(np.median(d[ok])),
        R.T @ T[:2, 2],
        math.degrees(math.atan2(T[1, 0], T[0, 0])),
        (dh + 180.0) % 360.0 - 180.0,
    )


def print_pairs(name: str, rows: list) -> None:
    if not rows:
        print(f"  {name}: none")
        return
    n = np.array([r[0] for r in rows])
    med = np.array([r[1] for r in rows])
    sh = np.array([np.linalg.norm(r[2]) for r in rows])
    yaw = np.abs([r[3] for r in rows])
    print(
        f"  {name:22s} {len(rows):4d} pairs, {np.median(n):4.0f} trees: "
        f"distance {np.median(med):.3f} m;"
        f" shift {np.median(sh):.3f} (p90 {np.percentile(sh, 90):.3f}) m;"
        f" yaw {np.median(yaw):.3f} (p90 {np.percentile(yaw, 90):.3f}) deg"
    )


def route_and_revisits(table, W) -> None:
    print("1. reference-placed trees, frame against frame:")
    n = len(W)
    for lag in (1, 2, 5, 10, 20):
        rows = [compare(table, W, k, k + lag) for k in range(0, n - lag, 3)]
        print_pairs(f"lag {lag}", [r for r in rows if r])
    pos = table.poses[table.frames][:, :2, 3]
    tree, rows = cKDTree(pos), []
    for k in range(0, n, 3):
        js = [j for j in tree.query_ball_point(pos[k], REVISIT_M) if j < k - REVISIT_GAP]
        if js:
            r = compare(table, W, min(js, key=lambda j: np.linalg.norm(pos[j] - pos[k])), k)
            rows += [r] if r else []
    print_pairs("revisits", rows)
    for name, sel in (
        ("same direction", lambda h: abs(h) < 60),
        ("opposite", lambda h: abs(h) > 120),
    ):
        part = [r for r in rows if sel(r[4])]
        if part:
            s = np.array([r[2] for r in part])
            print(
                f"    {name}: {len(part)} pairs, mean shift along / across track "
                f"{s[:, 0].mean():+.3f} / {s[:, 1].mean():+.3f} m (sd {s[:, 0].std():.3f} / "
                f"{s[:, 1].std():.3f})"
            )


def levelling(table) -> None:
    tilts = []
    for k in table.frames:
        a = table.axis[table.rows(k)]
        a = a[np.isfinite(a).all(axis=1)]
        if len(a) < 5:
            continue
        a = a * np.sign(a[:, 2:3] + 1e-12)  # stems point up
        m = np.median(a, axis=0)
        w = table.poses[k][:3, :3] @ (m / np.linalg.norm(m))
        tilts.append(math.degrees(math.acos(min(1.0, abs(w[2])))))
    t = np.array(tilts)
    frame_tilt = [math.degrees(math.acos(min(1.0, table.poses[k][2, 2]))) for k in table.frames]
    print(
        f"2. levelling: frames tilted {np.percentile(frame_tilt, 5):.1f}-"
        f"{np.percentile(frame_tilt, 95):.1f} deg (p5-p95); median stem axis vs world vertical "
        f"after the reference rotation: median {np.median(t):.2f}, "
        f"p90 {np.percentile(t, 90):.2f} deg"
    )


def clusters(table, W, every_m: float = 5.0):
    """Keyframes every `every_m`, their placed trees' (N,2), keyframe of each, cluster labels."""
    pos = table.poses[table.frames][:, :2, 3]
    kf = [0]
    for k in range(1, len(pos)):
        if np.linalg.norm(pos[k] - pos[kf[-1]]) >= every_m:
            kf.append(k)
    from forestslam.localization.localize import merge_close

    xy = np.concatenate([W[k] for k in kf])
    of = np.concatenate([np.full(len(W[k]), i) for i, k in enumerate(kf)])
    centres, labels = merge_close(xy, MATCH_M, return_labels=True)
    return np.array(kf), xy, of, centres, labels


def radial(table, kf, xy, of, centres, labels) -> None:
    seen = np.bincount(labels)
    ok = seen[labels] >= 4
    pos = table.poses[table.frames[kf]][:, :2, 3][of]
    ray = xy - pos
    rng = np.linalg.norm(ray, axis=1)
    ok &= rng > 1.0
    resid = np.sum((xy - centres[labels]) * ray / rng[:, None], axis=1)
    slope, icpt = np.polyfit(rng[ok], resid[ok], 1)
    spread = np.linalg.norm(xy - centres[labels], axis=1)[ok]
    print(
        f"3. radial: {ok.sum()} placements of trees seen >= 4 times: distance to cluster mean "
        f"median {np.median(spread):.3f} m; radial residual = {slope * 100:+.3f} % x range "
        f"{icpt * 100:+.2f} cm"
    )


def bound_figures(table) -> tuple[float, float, float]:
    """The landmark-graph bound of the whole session (section 4): ATE with SE(2) alignment,
    with Sim(2) alignment, and the Sim(2) scale."""
    kf, _, of, _, labels = clusters(table, world_trees(table))
    xy, ref = landmark_graph(table, kf, of, labels)
    sim, scale = sim2_ate(xy, ref)
    return planar_ate(xy, ref), sim, scale


def landmark_bound(table, kf, of, labels) -> None:
    xy, ref_xy = landmark_graph(table, kf, of, labels)
    sim, scale = sim2_ate(xy, ref_xy)
    se2 = planar_ate(xy, ref_xy)
    print(
        f"4. landmark graph, perfect association, {len(kf)} keyframes: ATE {se2:.3f} m "
        f"(SE(2)); {sim:.3f} m (Sim(2); the trees' map is {100 * (1 / scale - 1):+.3f} % "
        "against the reference)"
    )
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.maximum(
        np.linalg.norm(np.diff(ref_xy, axis=0), axis=1), 1e-9
    )
    parts = np.array_split(seg, 8)
    print(
        "   step length ratio graph / reference, by eighths of the route: "
        + " ".join(f"{100 * (np.median(q) - 1):+.2f}%" for q in parts)
    )


def landmark_graph(table, kf, of, labels) -> tuple[np.ndarray, np.ndarray]:
    """The batch landmark graph of section 4: keyframe positions (N,2) and reference (N,2)."""
    import gtsam

    from forestslam.localization.tables import query_xy
    from forestslam.multisession.tables_slam import level_origin
    from forestslam.slam.landmark_slam import matrix_pose2, planar, pose2_matrix

    T0 = np.linalg.inv(level_origin(table.poses[table.frames[0]]))
    frames = table.frames[kf]
    ref = np.stack([pose2_matrix(planar(T0 @ table.poses[k])) for k in frames])
    seen = np.bincount(labels)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(
        gtsam.PriorFactorPose2(
            0, gtsam.Pose2(*matrix_pose2(ref[0])), gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)
        )
    )
    free = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, math.radians(10.0)]))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    for i, k in enumerate(frames):
        values.insert(i, gtsam.Pose2(*matrix_pose2(ref[i])))
        if i:
            step = gtsam.Pose2(*matrix_pose2(np.linalg.inv(ref[i - 1]) @ ref[i]))
            graph.add(gtsam.BetweenFactorPose2(i - 1, i, step, free))
        obs, _ = query_xy(table, int(k), gravity="reference", max_range_m=RANGE_M)
        for p, j in zip(obs, labels[of == i], strict=True):
            if seen[j] < 2:
                continue
            r = float(np.hypot(*p))
            sd = 0.03 + 0.004 * r
            noise = gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Diagonal.Sigmas(np.array([sd / max(r, 0.5), sd]))
            )
            graph.add(
                gtsam.BearingRangeFactor2D(
                    i, gtsam.symbol("l", j), gtsam.Rot2(math.atan2(p[1], p[0])), r, noise
                )
            )
            if not values.exists(gtsam.symbol("l", j)):
                values.insert(
                    gtsam.symbol("l", j), gtsam.Point2(*(ref[i][:2, :2] @ p + ref[i][:2, 2]))
                )
    est = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    xy = np.array([est.atPose2(i).translation() for i in range(len(frames))])
    return xy, ref[:, :2, 2]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--session", default="wild_v03")
    args = ap.parse_args()
    path = DATA / args.session
    if not path.is_dir():
        print(f"skipped: {path} absent (shared real data not mounted)")
        return 0
    from forestslam.io.tree_tables import read_tree_table

    table = read_tree_table(path)
    print(f"{args.session}: {len(table.frames)} frames")
    W = world_trees(table)
    route_and_revisits(table, W)
    levelling(table)
    kf, xy, of, centres, labels = clusters(table, W)
    radial(table, kf, xy, of, centres, labels)
    landmark_bound(table, kf, of, labels)
    return 0


if __name__ == "__main__":
    sys.exit(main())
