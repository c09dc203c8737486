"""Per-scan DBH of a simulated sequence (`forestslam simulate` output) against its truth, by
stage: N scans spread over the sequence, truth stems (DBH >= 0.1 m) within 15 m moved into the
sensor frame by the true pose, detections matched within 0.5 m.
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
    err: dict[str, list] = {k: [] for k in ("silhouette", "circle", "cylinder", "chosen")}
    for k, scan in enumerate(read_scans(next(sim.glob("sequence.*")))):
        if k not in pick:
            continue
        T = np.linalg.inv(poses[k])
        local = transform_points(T, world)
        near = (np.linalg.norm(local[:, :2], axis=1) <= 15) & (trees["dbh_m"] >= 0.1)
        stems = detect(scan, sensor, cfg)
        for i in range(len(stems)):
            d = np.linalg.norm(local[:, :2] - stems.xy[i], axis=1)
            d[~near] = np.inf
            j = int(np.argmin(d))
            if d[j] > 0.5:
                continue
            truth = trees["dbh_m"][j]
            for m in ("silhouette", "circle", "cylinder"):
                if stems.diameters[i][m]["valid"]:
                    err[m].append(100 * (2 * stems.diameters[i][m]["radius"] - truth))
            if np.isfinite(stems.dbh[i]):
                err["chosen"].append(100 * (stems.dbh[i] - truth))
    return err


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sims", nargs="+", type=Path)
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--sensor", default=None, help="profile (default: from the folder name)")
    args = ap.parse_args()
    for sim in args.sims:
        sensor = args.sensor or ("hdl32" if "hdl32" in sim.name else "vlp16")
        err = evaluate(sim, args.scans, sensor)
        parts = []
        for m, e in err.items():
            e = np.asarray(e)
            parts.append(
                f"{m} n{len(e)} bias {e.mean():+.2f} MAE {np.abs(e).mean():.2f}"
                if len(e)
                else f"{m} -"
            )
        print(f"{sim.name} per-scan DBH (cm): " + "; ".join(parts))
        chosen = np.abs(np.asarray(err["chosen"]))
        if len(chosen):
            verdict = "ok" if chosen.mean() <= 2.5 else "MISS"
            print(f"{sim.name} per-scan DBH MAE {chosen.mean():.2f} cm (target <= 2.5): {verdict}")


if __name__ == "__main__":
    main()
