"""The SLAM back end on real tree observations (issue 21): Wild-Places Venman tree tables.

Each frame of ../shared/data/treeloc/wild_v03 (or --session) holds RealtimeTrees' local tree map
around reference pose k, in the frame of pose k. `forestslam.multisession.tables_slam` feeds it
to `LandmarkSlam`: the odometry is the reference trajectory with drift injected (`DriftInjector`,
default 2 % scale and 1 deg per 10 m), corrected by registering each frame's trees onto the
previous frame's; the trees, levelled by the reference gravity, are the observations; place
recognition (`multisession.loops`) runs at keyframes. The back end has to recover the reference.

Printed, planar ATE RMSE against the reference (SE(2) alignment of the whole trajectory, the figure
judged; beside it the ATE after a similarity alignment and how much larger the estimate's map is
than the reference, 1/s - 1; poses relative to the first pose's position and heading, world z
up): the drifted odometry, the
tree-registered odometry alone, the SLAM on the drifted odometry (no registration), the SLAM
without and with place recognition; place-recognition closures, tied tree pairs and false ones
(a closure is false when its tied trees lie > 1 m apart in the reference frame: the trees'
positions are their observations placed by the reference poses), CPU ms per frame, and the
place-recognition queries by outcome, made at a revisit (>= 6 query trees have their copy among
the queried map trees in the reference frame) or elsewhere (where rejection is right).
Last, the landmark-graph bound of the session (perfect association; treeloc_consistency_check.py,
section 4) with both alignments: the trees' own map is about 0.13-0.14 % smaller than the
reference, which a landmark SLAM cannot observe. Target (issue 21): <= 0.3 m over V03's 4.5 km,
no false loop closure.

    bench/treeloc_slam_bench.py [--session wild_v03] [--drift 0.02,1.0] [--frames N]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from forestslam.geometry import transform_points

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "treeloc"
MAX_FALSE_M = 1.0
PARTNER_M = 0.3  # a query tree's copy in the map (reference frame)
PARTNERS_MIN = 6  # PlaceRecognitionConfig.min_query_trees: a revisit place


def planar_ate(est_xy: np.ndarray, ref_xy: np.ndarray) -> float:
    from forestslam.geometry import rigid_fit

    T = rigid_fit(est_xy, ref_xy)
    moved = transform_points(T, est_xy)
    return float(np.sqrt(np.mean(np.sum((moved - ref_xy) ** 2, axis=1))))


def sim2_ate(est_xy: np.ndarray, ref_xy: np.ndarray) -> tuple[float, float]:
    """Planar ATE after a similarity alignment (Umeyama) and its scale s (ref ~ s R est + t):
    the trees' own map is 1/s - 1 larger than the reference. Printed beside the SE(2) figure
    (the one judged): a uniform scale is not observable from landmarks (see
    treeloc_consistency_check.py), so the two differ by what the trees' scale alone costs."""
    ce, cr = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    A, B = est_xy - ce, ref_xy - cr
    U, S, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.sum(A**2))
    moved = s * A @ R.T + cr
    return float(np.sqrt(np.mean(np.sum((moved - ref_xy) ** 2, axis=1)))), s


def reference_tree_positions(result, ref_poses: np.ndarray) -> dict[int, np.ndarray]:
    """Median reference-frame position of every landmark's observations."""
    from forestslam.slam.landmark_slam import planar, pose2_matrix

    per: dict[int, list] = {}
    for T, ids, xy in zip(ref_poses, result.landmark_ids, result.observations, strict=True):
        P = pose2_matrix(planar(T))
        world = xy @ P[:2, :2].T + P[:2, 2]
        for lm, w in zip(ids, world, strict=True):
            if lm >= 0:
                per.setdefault(int(lm), []).append(w)
    return {lm: np.median(np.array(w), axis=0) for lm, w in per.items()}


def recorded_place_recognition():
    """PlaceRecognition that keeps the tree pairs (older, newer) each closure tied, and every
    query: (kind "loop" / "relocalization", query landmark ids, map landmark ids, reason)."""
    from forestslam.multisession.loops import PlaceRecognition

    class Recorded(PlaceRecognition):
        closures: list
        queries: list

        def step(self, slam, keyframe, T_map_sensor):
            self._slam = slam
            before = slam.aliases()
            closed = super().step(slam, keyframe, T_map_sensor)
            if closed:
                after = slam.aliases()
                new = np.flatnonzero(after[: len(before)] != before)
                new = np.concatenate([new, len(before) + np.flatnonzero(after[len(before) :] >= 0)])
                self.closures.append(np.column_stack([after[new], new]))
            return closed

        def _query(self, xy, mapped, query_xy):
            loc, m_ids = super()._query(xy, mapped, query_xy)
            q_ids = cKDTree(xy).query(query_xy)[1]  # the queried trees are landmarks
            kind = "loop" if self._slam.lost_since is None else "relocalization"
            self.queries.append((kind, q_ids, m_ids.copy(), loc.reason or "accepted"))
            return loc, m_ids

    pr = Recorded()
    pr.closures, pr.queries = [], []
    return pr


def queries_by_place(pr, ref_trees: dict[int, np.ndarray]) -> dict[str, int]:
    """Loop and relocalization queries counted by outcome and by whether they were made at a
    revisit: at least PARTNERS_MIN query trees have a copy < PARTNER_M away among the queried
    map trees in the reference frame (the trees' positions are their reference placements)."""
    out: dict[str, int] = {}
    for kind, q_ids, m_ids, reason in pr.queries:
        q = np.array([ref_trees[int(i)] for i in q_ids if int(i) in ref_trees]).reshape(-1, 2)
        m = np.array([ref_trees[int(i)] for i in m_ids if int(i) in ref_trees]).reshape(-1, 2)
        partners = int((cKDTree(m).query(q)[0] < PARTNER_M).sum()) if len(q) and len(m) else 0
        place = "revisit" if partners >= PARTNERS_MIN else "no revisit"
        key = f"{kind} at {place}: {reason.split(':')[0]}"
        out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items()))


def false_closures(pr, ref_trees: dict[int, np.ndarray]) -> tuple[int, int, int]:
    """(false closures, tied pairs, pairs > MAX_FALSE_M apart in the reference frame)."""
    n_false = n_pairs = n_far = 0
    for pairs in pr.closures:
        d = [
            np.linalg.norm(ref_trees[int(a)] - ref_trees[int(b)])
            for a, b in pairs
            if int(a) in ref_trees and int(b) in ref_trees
        ]
        far = int(np.sum(np.array(d) > MAX_FALSE_M))
        n_pairs, n_far = n_pairs + len(d), n_far + far
        n_false += int(bool(d) and np.median(d) > MAX_FALSE_M)
    return n_false, n_pairs, n_far


def print_closures(res, pr, ref_poses: np.ndarray) -> int:
    """The place-recognition figures of a run; returns the number of false closures."""
    ref_trees = reference_tree_positions(res, ref_poses)
    n_false, n_pairs, n_far = false_closures(pr, ref_trees)
    st = res.stats
    print(
        f"  closures {st['loop_closures']}, relocalizations {st.get('relocalizations', 0)} "
        f"(tracking losses {st.get('losses', '?')}, revisits {st.get('revisits', '?')}), "
        f"false {n_false}; tied pairs {n_pairs}, "
        f"> {MAX_FALSE_M} m apart {n_far}"
    )
    print(f"  place recognition {pr.stats}")
    print(f"  rejected queries by reason: {pr.reasons}")
    for key, count in queries_by_place(pr, ref_trees).items():
        print(f"  {key}: {count}")
    return n_false


def print_bound(table, whole: bool) -> None:
    """The landmark-graph bound (treeloc_consistency_check.py, section 4) of the session."""
    if not whole:
        print("landmark bound: whole sessions only (run without --frames)")
        return
    from treeloc_consistency_check import bound_figures

    se2, sim, scale = bound_figures(table)
    print(
        f"{'landmark bound (perfect association)':44s} {se2:7.3f} {sim:7.3f} "
        f"{100 * (1 / scale - 1):+.3f} %"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--session", default="wild_v03")
    ap.add_argument("--drift", default="0.02,1.0")
    ap.add_argument("--frames", type=int, default=None, help="first N frames only")
    ap.add_argument("--max-range-m", type=float, default=20.0)
    ap.add_argument(
        "--no-ablations", action="store_true", help="only the SLAM with registration and closures"
    )
    ap.add_argument("--no-bound", action="store_true", help="skip the landmark-graph bound")
    args = ap.parse_args()
    path = DATA / args.session
    if not path.is_dir():
        print(f"skipped: {path} absent (shared real data not mounted)")
        return 0
    from forestslam.io.tree_tables import read_tree_table
    from forestslam.multisession.drift import DriftInjector
    from forestslam.multisession.tables_slam import level_origin, run_table_slam

    table = read_tree_table(path)
    frames = table.frames[: args.frames] if args.frames else table.frames
    T0_inv = np.linalg.inv(level_origin(table.poses[frames[0]]))
    ref_poses = np.einsum("ij,njk->nik", T0_inv, table.poses[frames])
    ref = ref_poses[:, :2, 3]
    length = float(np.sum(np.linalg.norm(np.diff(ref, axis=0), axis=1)))
    print(f"{args.session}: {len(frames)} frames, {length:.0f} m, drift {args.drift}")
    print(f"{'case':44s} {'ATE m':>7s} {'Sim(2)':>7s} {'size vs ref':>12s} {'ms/fr':>6s}")

    def row(label: str, xy: np.ndarray, ms: float | None = None) -> float:
        ate = planar_ate(xy, ref)
        sim, scale = sim2_ate(xy, ref)
        cpu = "" if ms is None else f"{ms:6.1f}"
        print(f"{label:44s} {ate:7.3f} {sim:7.3f} {100 * (1 / scale - 1):+10.3f} % {cpu}")
        return ate

    def case(register: bool, pr):
        drift = DriftInjector.parse(args.drift)
        return run_table_slam(
            table, frames, drift, None, pr, register=register, max_range_m=args.max_range_m
        )

    if not args.no_ablations:
        plain = case(False, None)
        row("SLAM on drifted odometry, no registration", plain.slam_xy, plain.cpu_ms_per_frame)
    worst = math.inf
    for with_pr in (True,) if args.no_ablations else (False, True):
        pr = recorded_place_recognition() if with_pr else None
        res = case(True, pr)
        if with_pr:
            row("drifted odometry", res.odometry_xy)
            row(f"tree-registered odometry ({res.fallbacks} fallbacks)", res.fed_xy)
        label = "SLAM " + ("with" if with_pr else "without") + " place recognition"
        ate = row(label, res.slam_xy, res.cpu_ms_per_frame)
        if pr is not None:
            worst = ate if print_closures(res, pr, ref_poses) == 0 else math.inf
    if not args.no_bound:
        print_bound(table, args.frames is None)
    met = worst <= 0.3
    print(
        f"target <= 0.3 m (SE(2) ATE) with place recognition, no false closure: "
        f"{'met' if met else 'MISSED'}"
    )
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
