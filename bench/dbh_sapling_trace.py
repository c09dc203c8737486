"""Where the thin mapped trees (saplings) lose their DBH, stage by stage, on a simulated
sequence: runs `forestslam run` in-process (the tree map kept), scores it against the truth
(0.5 m gate), and for every truth stem under --max-dbh that the map holds traces

- per scan (perception on each scan, the true pose moving the truth into the sensor frame):
  scans within 30 m; with >= 1 return within the stem's radius + 8 cm of its axis (0.3-3 m
  above ground); with >= 2 scan lines of >= 2 returns within +-1 m of breast height (what a
  silhouette needs); with a detected stem within 0.3 m; with an accepted silhouette, and with
  its radius below DiameterConfig.min_radius_m (the floor) or its lines too spread; with a
  valid band circle; with a per-scan DBH;
- in the tree map (the run's own, SLAM poses): scans that observed the tree, of those with a
  per-scan DBH, with band returns, per-scan DBHs from ranges that resolve it, and the first
  test of TreeMap.dbh it fails, in this order: is_stem's band support, is_stem's DBH share
  (over the resolving ranges), fewer than 3 per-scan DBHs from resolving ranges and no window
  ("below resolution"), per-scan DBHs that disagree.

Also what the mapped objects without a truth stem are (the nearest truth stem and its DBH,
the nearest other mapped tree: a split tree lies within ~1 m of a truth stem that another
mapped tree holds).
Usage: python bench/dbh_sapling_trace.py SIM OUT [--sensor vlp16] [--max-dbh 0.07]
[--every 1] (SIM: a `forestslam simulate` folder with truth/; OUT: where the run goes)."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

import forestslam.mapping.tree_map as tm
from forestslam.evaluation.report import evaluate_run
from forestslam.evaluation.trees import tree_errors
from forestslam.io import read_scans, read_trees_csv, read_tum
from forestslam.mapping.config import MappingConfig
from forestslam.perception import PerceptionConfig, detect
from forestslam.runner import run
from forestslam.sensors import load_profile

_CAPTURED: dict = {}


def run_with_tree_map(bag: Path, sensor: str, out: Path):
    """`forestslam run` in-process; returns the TreeMap the run's trees.csv came from."""
    table = tm.TreeMap.table

    def capture(self, *a, **k):
        _CAPTURED["map"] = self
        return table(self, *a, **k)

    tm.TreeMap.table = capture
    try:
        run(bag, sensor, out, progress=False, overwrite=True)
    finally:
        tm.TreeMap.table = table
    return _CAPTURED["map"]


def mapped_trees(out: Path, truth: Path) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """(est table, truth table, truth index per est row (-1 none), alignment)."""
    evaluate_run(out, truth)
    alignment = np.asarray(
        json.loads((out / "metrics.json").read_text())["trajectory"]["alignment"]
    )
    est = read_trees_csv(out / "trees.csv")
    tru = read_trees_csv(truth / "trees.csv")
    _, poses = read_tum(truth / "trajectory.tum")
    est_xyz = np.c_[est["x"], est["y"], np.nan_to_num(est["z"])]
    r = tree_errors(
        est_xyz, est["dbh_m"], np.c_[tru["x"], tru["y"]], tru["dbh_m"], poses[:, :2, 3], alignment
    )
    return est, tru, r["match_est_to_truth"], alignment


def per_scan_trace(sim: Path, sensor: str, targets: np.ndarray, tru: dict, every: int) -> dict:
    """Per target truth stem, counts of scans reaching each perception stage (module doc)."""
    profile = load_profile(sensor)
    _, poses = read_tum(sim / "truth" / "trajectory.tum")
    cfg = PerceptionConfig()
    floor = cfg.diameter.min_radius_m
    base = np.c_[tru["x"], tru["y"], tru["z_ground"]][targets]
    radius = 0.5 * tru["dbh_m"][targets]
    stages = (
        "in_30m",
        "hit",
        "2_lines_2_returns",
        "detected",
        "sil_lines>=2",
        "sil_valid",
        "sil_r<floor",
        "circle_valid",
        "per_scan_dbh",
    )
    counts = {int(t): Counter() for t in targets}
    ranges: dict[int, list] = {int(t): [] for t in targets}
    sil_r: dict[int, list] = {int(t): [] for t in targets}
    for k, scan in enumerate(read_scans(next(sim.glob("sequence.*")))):
        if k % every:
            continue
        T = np.linalg.inv(poses[k])
        local = base @ T[:3, :3].T + T[:3, 3]
        rng = np.linalg.norm(local[:, :2], axis=1)
        near = np.flatnonzero(rng <= 30)
        if not len(near):
            continue
        p = scan.points
        stems = None
        for j in near:
            t = int(targets[j])
            c = counts[t]
            c["in_30m"] += 1
            d = np.linalg.norm(p[:, :2] - local[j, :2], axis=1)
            h = p[:, 2] - local[j, 2]
            on = (d <= radius[j] + 0.08) & (h >= 0.3) & (h <= 3.0)
            if not on.any():
                continue
            c["hit"] += 1
            ranges[t].append(rng[j])
            band = on & (np.abs(h - 1.3) <= 1.0)
            if scan.ring is not None and band.any():
                per_line = np.bincount(np.asarray(scan.ring)[band].astype(int))
                if np.count_nonzero(per_line >= 2) >= 2:
                    c["2_lines_2_returns"] += 1
            if stems is None:
                stems = detect(scan, profile, cfg)
            if not len(stems):
                continue
            dd = np.linalg.norm(stems.xy - local[j, :2], axis=1)
            i = int(np.argmin(dd))
            if dd[i] > 0.3:
                continue
            c["detected"] += 1
            fit = stems.diameters[i]
            if fit.silhouette.inliers >= 2:
                c["sil_lines>=2"] += 1
                if np.isfinite(fit.silhouette.radius):
                    sil_r[t].append((rng[j], fit.silhouette.radius))
                if fit.silhouette.radius < floor:
                    c["sil_r<floor"] += 1
            c["sil_valid"] += bool(fit.silhouette.valid)
            c["circle_valid"] += bool(fit.circle.valid)
            c["per_scan_dbh"] += bool(np.isfinite(stems.dbh[i]))
    return {"stages": stages, "counts": counts, "ranges": ranges, "sil_r": sil_r}


def map_stage(trees: tm.TreeMap, landmark: int) -> dict:
    """The tree map's evidence for one landmark and the first test of TreeMap.dbh it fails."""
    tree = trees.trees.get(landmark)
    if tree is None:
        return {"why": "never in the tree map"}
    cfg = trees.cfg
    out = {
        "scans": tree.n_scans,
        "with_dbh": tree.n_scans_dbh,
        "band": tree.n_support_scans,
        "windows": len(tree.measurements),
    }
    d = trees._resolved_scans(tree)
    out["resolved"] = len(d)
    if tree.n_support_scans < cfg.dbh_min_window_scans:
        out["why"] = "is_stem: band support"
    elif not trees.is_stem(tree):
        out["why"] = "is_stem: per-scan DBH in < half the scans (at ranges resolving it)"
    elif trees._scan_estimate(tree) is None and trees._window_estimate(tree) is None:
        out["why"] = (
            f"per-scan DBH disagree (median {100 * np.median(d):.1f} cm, spread "
            f"{100 * tm._spread(d):.1f}) and no window"
            if len(d) >= cfg.dbh_fallback_min_scans
            else "below resolution: < 3 per-scan DBH from ranges resolving it, no window"
        )
    else:
        out["why"] = "has a DBH"
    return out


def unmatched_objects(est: dict, tru: dict, match: np.ndarray, alignment: np.ndarray) -> list:
    """Per mapped tree without a truth stem: distance to the nearest truth stem, its DBH, and
    whether that stem is held by another mapped tree (a split tree) or by none."""
    xy = (np.c_[est["x"], est["y"], np.nan_to_num(est["z"]), np.ones(len(est["x"]))] @ alignment.T)[
        :, :2
    ]
    txy = np.c_[tru["x"], tru["y"]]
    held = set(match[match >= 0].tolist())
    out = []
    for i in np.flatnonzero(match < 0):
        d = np.linalg.norm(txy - xy[i], axis=1)
        j = int(np.argmin(d))
        out.append(
            {
                "id": int(est["id"][i]),
                "nearest_m": round(float(d[j]), 2),
                "truth_dbh_cm": round(100 * float(tru["dbh_m"][j]), 1),
                "held_by_other": j in held,
                "has_dbh": bool(np.isfinite(est["dbh_m"][i])),
                "obs": int(est["observations"][i]),
            }
        )
    return out


def resolved(sil: list, dbh: float, sensor: str) -> list:
    """Silhouette radii of the scans whose azimuth step spans at most 1 / dbh_resolve_steps of
    the true stem (the tree map's range gate)."""
    step = np.radians(load_profile(sensor).azimuth_resolution_deg)
    return [r for rho, r in sil if rho * step * MappingConfig().dbh_resolve_steps <= dbh]


def tree_row(tree_id: int, truth_cm: float, map_cm: float, c: Counter, stages, rng, sil, near, m):
    """One printed row: the stage counts, ranges, silhouette DBHs and the map's verdict."""
    row = f"{tree_id:5d} {truth_cm:6.1f} {map_cm:6.1f} " + " ".join(f"{c[s]:8d}" for s in stages)
    if rng:
        row += f"  range {np.min(rng):.1f}-{np.median(rng):.1f} m"
    if sil:
        row += f" sil DBH median {200 * np.median([r for _, r in sil]):.1f} cm"
    if near:
        row += f" (resolving ranges {200 * np.median(near):.1f} cm, {len(near)})"
    return row + f" | map {m}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sim", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--sensor", default=None)
    ap.add_argument("--max-dbh", type=float, default=0.07)
    ap.add_argument("--every", type=int, default=1, help="perception on every N-th scan")
    args = ap.parse_args()
    sensor = args.sensor or ("hdl32" if "hdl32" in args.sim.name else "vlp16")
    truth = args.sim / "truth"
    trees = run_with_tree_map(args.sim / "sequence.bag", sensor, args.out)
    est, tru, match, alignment = mapped_trees(args.out, truth)
    rows = np.flatnonzero((match >= 0) & (tru["dbh_m"][np.maximum(match, 0)] < args.max_dbh))
    no_dbh = ~np.isfinite(est["dbh_m"])
    print(
        f"{args.sim}: {len(est['id'])} mapped, {int(no_dbh.sum())} without DBH; "
        f"{len(rows)} mapped truth stems < {100 * args.max_dbh:.0f} cm, "
        f"{int(no_dbh[rows].sum())} of them without DBH"
    )
    targets = match[rows]
    trace = per_scan_trace(args.sim, sensor, targets, tru, args.every)
    print(
        f"{'tree':>5s} {'truth':>6s} {'map':>6s} " + " ".join(f"{s:>8s}" for s in trace["stages"])
    )
    total = Counter()
    whys = Counter()
    for r, t in zip(rows, targets, strict=True):
        c = trace["counts"][int(t)]
        total.update(c)
        rng = trace["ranges"][int(t)]
        m = map_stage(trees, int(est["id"][r]) - 1)
        whys[m["why"]] += 1
        sil = trace["sil_r"][int(t)]
        near = resolved(sil, tru["dbh_m"][t], sensor)
        print(
            tree_row(
                int(est["id"][r]),
                100 * tru["dbh_m"][t],
                100 * est["dbh_m"][r],
                c,
                trace["stages"],
                rng,
                sil,
                near,
                m,
            )
        )
    print(f"{'all':>5s} {'':6s} {'':6s} " + " ".join(f"{total[s]:8d}" for s in trace["stages"]))
    print("map stage:", dict(whys))
    objs = unmatched_objects(est, tru, match, alignment)
    split = sum(o["held_by_other"] and o["nearest_m"] <= 1.0 for o in objs)
    print(
        f"mapped trees without a truth stem: {len(objs)} ({split} within 1 m of a stem another "
        "mapped tree holds: split trees)"
    )
    for o in objs:
        print("  ", o)


if __name__ == "__main__":
    main()
