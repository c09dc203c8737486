"""Per-tree DBH of a `forestslam run` against simulator truth (after `forestslam evaluate`):
bias, MAE, RMSE, share of mapped trees with a DBH, dbh_std_m calibration (share of trees within
+-1 sigma of the truth) and the worst trees. Usage: python bench/dbh_run_trees.py RUN TRUTH [...]
(pairs of run and truth folders)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from forestslam.evaluation.trees import tree_errors
from forestslam.io import read_trees_csv, read_tum


def report(run: Path, truth: Path) -> dict:
    metrics = json.loads((run / "metrics.json").read_text())
    alignment = np.asarray(metrics["trajectory"]["alignment"])
    est = read_trees_csv(run / "trees.csv")
    tru = read_trees_csv(truth / "trees.csv")
    _, poses = read_tum(truth / "trajectory.tum")
    est_xyz = np.c_[est["x"], est["y"], np.nan_to_num(est["z"])]
    r = tree_errors(
        est_xyz, est["dbh_m"], np.c_[tru["x"], tru["y"]], tru["dbh_m"], poses[:, :2, 3], alignment
    )
    m = r["match_est_to_truth"]
    k = np.nonzero(m >= 0)[0]
    e = 100 * (est["dbh_m"][k] - tru["dbh_m"][m[k]])
    sd = 100 * est["dbh_std_m"][k]
    ok = np.isfinite(e)
    cal = np.abs(e[ok & np.isfinite(sd)]) <= sd[ok & np.isfinite(sd)]
    out = {
        "trees": len(est["dbh_m"]),
        "with_dbh": float(np.isfinite(est["dbh_m"]).mean()),
        "matched": len(k),
        "bias_cm": float(np.mean(e[ok])),
        "mae_cm": float(np.mean(np.abs(e[ok]))),
        "median_abs_cm": float(np.median(np.abs(e[ok]))),
        "rmse_cm": float(np.sqrt(np.mean(e[ok] ** 2))),
        "within_1sigma": float(cal.mean()) if len(cal) else float("nan"),
        "with_sigma": int(len(cal)),
    }
    worst = np.argsort(-np.abs(np.nan_to_num(e)))[:3]
    out["worst"] = [
        (
            int(est["id"][k[i]]),
            round(float(e[i]), 2),
            round(float(sd[i]), 2),
            int(est["observations"][k[i]]),
        )
        for i in worst
    ]
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    for run, truth in zip(args[::2], args[1::2], strict=True):
        r = report(Path(run), Path(truth))
        print(
            f"{run}: trees {r['trees']} with DBH {r['with_dbh']:.2f}, matched {r['matched']}: "
            f"bias {r['bias_cm']:+.2f} cm, MAE {r['mae_cm']:.2f}, median |e| "
            f"{r['median_abs_cm']:.2f}, RMSE {r['rmse_cm']:.2f}; within 1 sigma "
            f"{r['within_1sigma']:.2f} of {r['with_sigma']}; worst (id, err, sigma, obs) "
            f"{r['worst']}"
        )
