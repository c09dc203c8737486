"""Evaluate a run directory against a simulator truth directory: metrics.json and errors.png.

Run dir: trajectory.tum (else odometry.tum), odometry.tum (optional), trees.csv (optional,
columns x,y[,z],dbh_m). Truth dir: trajectory.tum (T_world_sensor), trees.csv
(id,x,y,z_ground,dbh_m,height_m, world frame). Trees are moved by the trajectory's alignment;
the true path is the truth trajectory over the time span of the run.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.evaluation.trajectory import associate, trajectory_errors
from forestslam.evaluation.trees import tree_errors

log = logging.getLogger(__name__)


def _plain(d: dict) -> dict:
    """JSON-ready copy: arrays to lists, NaN to None, per-tree match arrays left out."""
    out = {}
    for k, v in d.items():
        if k == "match_est_to_truth":
            continue
        if isinstance(v, np.ndarray):
            out[k] = v.tolist()
        elif isinstance(v, float) and not np.isfinite(v):
            out[k] = None
        else:
            out[k] = v
    return out


def evaluate_run(
    run_dir: str | Path,
    truth_dir: str | Path,
    gate_m: float = 0.5,
    min_dbh_m: float = 0.1,
    max_dist_m: float = 15.0,
    max_dt: float = 0.02,
    plot: bool = True,
) -> dict:
    """Metrics of a run against the truth; writes run_dir/metrics.json (and errors.png)."""
    from forestslam.io import read_trees_csv, read_tum
    from forestslam.io.atomic import atomic_write_text

    run_dir, truth_dir = Path(run_dir), Path(truth_dir)
    est_path = _estimate_path(run_dir, truth_dir)
    gt_stamps, gt_poses = read_tum(truth_dir / "trajectory.tum")
    est_stamps, est_poses = read_tum(est_path)
    if len(est_stamps) == 0:
        raise InputError(f"{est_path}: empty trajectory")
    metrics: dict = {
        "run_dir": str(run_dir),
        "truth_dir": str(truth_dir),
        "trajectory_file": est_path.name,
    }
    traj = trajectory_errors(est_stamps, est_poses, gt_stamps, gt_poses, max_dt=max_dt)
    metrics["trajectory"] = _plain(traj)
    odom_path = run_dir / "odometry.tum"
    if odom_path.is_file() and est_path != odom_path:
        s, p = read_tum(odom_path)
        if len(s):
            metrics["odometry"] = _plain(trajectory_errors(s, p, gt_stamps, gt_poses, max_dt))

    ia, ib = associate(est_stamps, gt_stamps, max_dt)
    path_xy = gt_poses[ib.min() : ib.max() + 1, :2, 3]
    trees, est, truth = None, None, None
    if (run_dir / "trees.csv").is_file() and (truth_dir / "trees.csv").is_file():
        est = read_trees_csv(run_dir / "trees.csv")
        truth = read_trees_csv(truth_dir / "trees.csv")
        gates = {"gate_m": gate_m, "min_dbh_m": min_dbh_m, "max_dist_m": max_dist_m}
        trees = _tree_metrics(est, truth, path_xy, traj["alignment"], gates)
        metrics["trees"] = _plain(trees)
        metrics["trees"].update(gate_m=gate_m, min_dbh_m=min_dbh_m, max_dist_m=max_dist_m)
    ground = _ground_metrics(run_dir, truth_dir, traj["alignment"])
    if ground:
        metrics["ground"] = ground
    atomic_write_text(run_dir / "metrics.json", json.dumps(metrics, indent=1))
    if plot:
        from forestslam.evaluation.plot import plot_errors

        plot_errors(
            run_dir / "errors.png",
            est_stamps[ia],
            est_poses[ia],
            gt_poses[ib],
            traj["alignment"],
            trees,
            est,
            truth,
        )
    return metrics


def _estimate_path(run_dir: Path, truth_dir: Path) -> Path:
    """The run's trajectory to score: trajectory.tum, else odometry.tum (inputs checked)."""
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: run directory not found")
    if not (truth_dir / "trajectory.tum").is_file():
        raise InputError(f"{truth_dir}: no trajectory.tum (expected a simulator truth directory)")
    est_path = run_dir / "trajectory.tum"
    if not est_path.is_file():
        est_path = run_dir / "odometry.tum"
    if not est_path.is_file():
        raise InputError(f"{run_dir}: neither trajectory.tum nor odometry.tum found")
    return est_path


def _tree_metrics(est: dict, truth: dict, path_xy, alignment, gates: dict) -> dict:
    """tree_errors of the run's tree table against the truth's (3D when every z is known)."""
    n = len(est.get("x", []))
    if "z" in est and n and np.isfinite(est["z"]).all():
        est_xyz = np.column_stack([est["x"], est["y"], est["z"]])
    else:
        est_xyz = np.column_stack([est.get("x", np.zeros(0)), est.get("y", np.zeros(0))])
    est_dbh = est.get("dbh_m", np.full(n, np.nan))
    truth_xy = np.column_stack([truth["x"], truth["y"]])
    return tree_errors(est_xyz, est_dbh, truth_xy, truth["dbh_m"], path_xy, alignment, **gates)


def _ground_metrics(run_dir: Path, truth_dir: Path, alignment: np.ndarray) -> dict:
    """DTM cells and ground-map points (map3d runs) against the simulator's terrain."""
    from forestslam.evaluation.ground import dtm_cells, height_errors, load_truth_terrain

    files = {"dtm": run_dir / "dtm.npz", "ground_points": run_dir / "ground.ply"}
    if not any(f.is_file() for f in files.values()):
        return {}
    terrain = load_truth_terrain(truth_dir)
    if terrain is None:
        return {}
    out = {}
    if files["dtm"].is_file():
        out["dtm"] = height_errors(dtm_cells(files["dtm"]), alignment, terrain)
    if files["ground_points"].is_file():
        from forestslam.io import read_cloud

        out["ground_points"] = height_errors(
            read_cloud(files["ground_points"]).points, alignment, terrain
        )
    return out


def format_table(metrics: dict) -> str:
    """The printed summary of `evaluate_run` (one metric per line)."""

    def f(v, unit="", scale=1.0, digits=3):
        return "n/a" if v is None else f"{v * scale:.{digits}f}{unit}"

    rows = []
    t = metrics["trajectory"]
    o = metrics.get("odometry")
    rows.append(
        (
            "",
            "SLAM" if metrics["trajectory_file"] == "trajectory.tum" else "odometry",
            "odometry" if o else "",
        )
    )
    for name, key, unit in (
        ("ATE RMSE", "ate_rmse_m", " m"),
        ("RPE over 10 m", "rpe_percent_10m", " %"),
        ("final drift", "final_drift_m", " m"),
    ):
        rows.append((name, f(t[key], unit), f(o[key], unit) if o else ""))
    rows.append(("scans associated", str(t["n_associated"]), str(o["n_associated"]) if o else ""))
    tr = metrics.get("trees")
    if tr:
        rows.append(
            (
                "trees (truth / est / matched)",
                f"{tr['n_truth']} / {tr['n_est']} / {tr['n_matched']}",
                "",
            )
        )
        rows.append(("tree recall", f(tr["recall"]), ""))
        rows.append(("tree precision", f(tr["precision"]), ""))
        rows.append(("mean position error", f(tr["mean_position_error_m"], " m"), ""))
        rows.append(("DBH MAE", f(tr["dbh_mae_m"], " cm", 100, 2), ""))
        rows.append(("DBH RMSE", f(tr["dbh_rmse_m"], " cm", 100, 2), ""))
        rows.append(("DBH bias", f(tr["dbh_bias_m"], " cm", 100, 2), ""))
    for name, g in metrics.get("ground", {}).items():
        label = "DTM" if name == "dtm" else "ground points"
        unit = "cells" if name == "dtm" else "points"
        rows.append(
            (
                f"{label} vs terrain: |dz| median / p90",
                f"{f(g['median_abs_m'], ' m')} / {f(g['p90_abs_m'], ' m')}",
                f"{g['n']} {unit}",
            )
        )
        rows.append(
            (
                f"{label} vs terrain: bias / RMSE",
                f"{f(g['bias_m'], ' m')} / {f(g['rmse_m'], ' m')}",
                "",
            )
        )
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    return "\n".join(f"{a:<{w0}}  {b:>{w1}}  {c}".rstrip() for a, b, c in rows)
