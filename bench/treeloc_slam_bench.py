"""The SLAM back end on real tree observations (issue 21): Wild-Places Venman tree tables.

Each frame of ../shared/data/treeloc/wild_v03 (or --session) holds RealtimeTrees' local tree map
around reference pose k, in the frame of pose k. The trees, levelled by the reference roll and
pitch, are fed as observations to `LandmarkSlam`; the odometry between frames is the reference
trajectory with drift injected (`DriftInjector`, default 2 % scale and 1 deg per 10 m), so the
back end has to recover the reference from the trees. Place recognition runs as in a run.

Printed: planar ATE RMSE against the reference (SE(2) alignment of the whole trajectory) of the
drifted odometry, of the SLAM without and with place recognition, loop closures, and ms per
frame. Target (issue 21): <= 0.3 m RMSE over V03's 4.5 km, no false loop closure (a closure is
false when its tied trees lie > 1 m apart in the reference frame).

    bench/treeloc_slam_bench.py [--session wild_v03] [--drift 0.02,1.0] [--frames N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from forestslam.geometry import transform_points

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "treeloc"


def planar_ate(est_xy: np.ndarray, ref_xy: np.ndarray) -> float:
    from forestslam.geometry import rigid_fit

    T = rigid_fit(est_xy, ref_xy)
    moved = transform_points(T, est_xy)
    return float(np.sqrt(np.mean(np.sum((moved - ref_xy) ** 2, axis=1))))


def run(table, frames, drift_text: str, place_recognition: bool, max_range_m: float):
    from forestslam.localization.tables import query_xy
    from forestslam.multisession.drift import DriftInjector
    from forestslam.multisession.loops import PlaceRecognition, PlaceRecognitionConfig
    from forestslam.slam import LandmarkSlam
    from forestslam.slam.config import SlamConfig

    drift = DriftInjector.parse(drift_text)
    slam = LandmarkSlam(SlamConfig(max_observation_range_m=max_range_m, keyframe_distance_m=0.5))
    pr = PlaceRecognition(PlaceRecognitionConfig(enabled=place_recognition))
    T0_inv = np.linalg.inv(table.poses[frames[0]])
    odom = []
    cov = np.diag([0.05**2, 0.05**2, np.radians(0.5) ** 2])
    t0 = time.process_time()
    for k in frames:
        T_odom = drift.apply(T0_inv @ table.poses[k])
        odom.append(T_odom[:2, 3])
        xy, _ = query_xy(table, int(k), gravity="reference", max_range_m=max_range_m)
        res = slam.add_scan(float(table.stamps[k]), T_odom, cov, False, xy)
        if res.keyframe is not None:
            pr.step(slam, res.keyframe, res.T_map_sensor)
    ms = 1e3 * (time.process_time() - t0) / len(frames)
    _, est = slam.trajectory()
    return np.array(odom), est[:, :2, 3], slam, pr, ms


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--session", default="wild_v03")
    ap.add_argument("--drift", default="0.02,1.0")
    ap.add_argument("--frames", type=int, default=None, help="first N frames only")
    ap.add_argument("--max-range-m", type=float, default=20.0)
    args = ap.parse_args()
    path = DATA / args.session
    if not path.is_dir():
        print(f"skipped: {path} absent (shared real data not mounted)")
        return 0
    from forestslam.io.tree_tables import read_tree_table

    table = read_tree_table(path)
    frames = table.frames[: args.frames] if args.frames else table.frames
    T0_inv = np.linalg.inv(table.poses[frames[0]])
    ref = np.einsum("ij,njk->nik", T0_inv, table.poses[frames])[:, :2, 3]
    length = float(np.sum(np.linalg.norm(np.diff(ref, axis=0), axis=1)))
    print(f"{args.session}: {len(frames)} frames, {length:.0f} m, drift {args.drift}")
    print(f"{'case':40s} {'ATE m':>8s} {'closures':>9s} {'ms/frame':>9s}")
    worst = 0.0
    for pr_on in (False, True):
        odom, est, slam, pr, ms = run(table, frames, args.drift, pr_on, args.max_range_m)
        if not pr_on:
            print(f"{'drifted odometry':40s} {planar_ate(odom, ref):8.3f}")
        label = "SLAM " + ("with" if pr_on else "without") + " place recognition"
        ate = planar_ate(est, ref)
        print(f"{label:40s} {ate:8.3f} {pr.stats['closures']:9d} {ms:9.1f}")
        worst = max(worst, ate) if pr_on else worst
    met = worst <= 0.3
    print(f"target <= 0.3 m with place recognition: {'met' if met else 'MISSED'}")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
