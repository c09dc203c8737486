"""Per-scan DBH of a simulated sequence (`forestslam simulate` output) against its truth, by
stage: N scans spread over the sequence, truth stems (DBH >= 0.1 m) within 15 m moved into the
sensor frame by the true pose, detections matched within 0.5 m. Per stage the DBH bias / MAE
and the stem centre's range error (estimated minus true distance from the sensor: negative =
pulled toward the sensor), and the share of matched stems that carry a DBH; `reported` is the
DBH a scan reports (Stems.reported_dbh: expected error dbh_std <= 2 cm), printed with the share
of matched stems that carry one, and the share of chosen DBH within +-1 dbh_std of the truth.
Usage: python bench/dbh_scan_seq.py SIM_DIR [SIM_DIR ...] [--scans 40] [--sensor vlp16]"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from forestslam.geometry import transform_points
from forestslam.io import read_scans, read_trees_csv, read_tum
from forestslam.perception import PerceptionConfig, detect


def evaluate(sim: Path, n_scans: int, sensor: str) -> dict[str, list]:
    _, poses = read_tum(sim / "truth" / "trajectory.tum")
    trees = read_trees_csv(sim / "truth" / "trees.csv")
    world = np.c_[trees["x"], trees["y"], trees["z_ground"] + 1.3]
    pick = set(np.linspace(0, len(poses) - 1, n_scans).astype(int).tolist())
    cfg = PerceptionConfig()
    cfg.diameter.fit_all = True
    stages = ("silhouette", "circle", "cylinder", "chosen", "reported")
    err: dict[str, list] = {k: [] for k in stages}
    rng_err: dict[str, list] = {k: [] for k in stages}
    matched, within = 0, []
    for k, scan in enumerate(read_scans(next(sim.glob("sequence.*")))):
        if k not in pick:
            continue
        T = np.linalg.inv(poses[k])
        local = transform_points(T, world)
        near = (np.linalg.norm(local[:, :2], axis=1) <= 15) & (trees["dbh_m"] >= 0.1)
        stems = detect(scan, sensor, cfg)
        reported, dbh_std = stems.reported_dbh(), stems.dbh_std
        for i in range(len(stems)):
            d = np.linalg.norm(local[:, :2] - stems.xy[i], axis=1)
            d[~near] = np.inf
            j = int(np.argmin(d))
            if d[j] > 0.5:
                continue
            truth = trees["dbh_m"][j]
            true_range = np.linalg.norm(local[j, :2])
            matched += 1
            for m in ("silhouette", "circle", "cylinder"):
                fit = getattr(stems.diameters[i], m)
                if fit.valid:
                    err[m].append(100 * (2 * fit.radius - truth))
                    centre = np.asarray(fit.centre)[:2]
                    rng_err[m].append(100 * (np.linalg.norm(centre) - true_range))
            if np.isfinite(stems.dbh[i]):
                err["chosen"].append(100 * (stems.dbh[i] - truth))
                within.append(abs(stems.dbh[i] - truth) <= dbh_std[i])
            if np.isfinite(reported[i]):
                err["reported"].append(100 * (reported[i] - truth))
            rng_err["chosen"].append(100 * (np.linalg.norm(stems.xy[i]) - true_range))
    return err, rng_err, matched, float(np.mean(within)) if within else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sims", nargs="+", type=Path)
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--sensor", default=None, help="profile (default: from the folder name)")
    args = ap.parse_args()
    for sim in args.sims:
        sensor = args.sensor or ("hdl32" if "hdl32" in sim.name else "vlp16")
        err, rng_err, matched, within = evaluate(sim, args.scans, sensor)
        parts, centre = [], []
        for m, e in err.items():
            e, r = np.asarray(e), np.asarray(rng_err[m])
            parts.append(
                f"{m} n{len(e)} bias {e.mean():+.2f} MAE {np.abs(e).mean():.2f}"
                if len(e)
                else f"{m} -"
            )
            centre.append(f"{m} {np.mean(r):+.2f} (median {np.median(r):+.2f})" if len(r) else "-")
        print(f"{sim.name} per-scan DBH (cm): " + "; ".join(parts))
        print(f"{sim.name} per-scan centre range error (cm): " + "; ".join(centre))
        for m in ("chosen", "reported"):
            e = np.abs(np.asarray(err[m]))
            if len(e):
                verdict = "ok" if e.mean() <= 2.5 else "MISS"
                print(
                    f"{sim.name} per-scan {m} DBH MAE {e.mean():.2f} cm (target <= 2.5): "
                    f"{verdict}; {len(e)} of {matched} matched stems carry one "
                    f"({100 * len(e) / max(matched, 1):.0f} %)"
                )
        print(f"{sim.name} per-scan chosen DBH within +-1 dbh_std: {100 * within:.0f} %")


if __name__ == "__main__":
    main()
