"""The evaluation figure: aligned trajectory and trees, ATE over time, DBH and position errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from forestslam.geometry import transform_xy


def plot_errors(
    path: Path,
    stamps: np.ndarray,
    est_poses: np.ndarray,
    gt_poses: np.ndarray,
    alignment: np.ndarray,
    trees: dict | None,
    est_trees: dict | None,
    truth_trees: dict | None,
) -> None:
    """Four panels into `path` (PNG): associated estimated/true poses (N,4,4), the (4,4)
    alignment, and optionally `tree_errors` output with the estimated / true tree columns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from forestslam.io.atomic import atomic_write

    aligned = np.einsum("ij,njk->nik", alignment, est_poses)[:, :3, 3]
    gt = gt_poses[:, :3, 3]
    err = np.linalg.norm(aligned - gt, axis=1)
    fig, axes = plt.subplots(2, 2, figsize=(12, 10), dpi=100)
    ax = axes[0, 0]
    ax.plot(gt[:, 0], gt[:, 1], "k-", lw=1, label="truth")
    ax.plot(aligned[:, 0], aligned[:, 1], "tab:blue", lw=1, label="estimate (aligned)")
    if trees is not None and est_trees is not None and truth_trees is not None:
        match = trees["match_est_to_truth"]
        ex = np.column_stack([est_trees["x"], est_trees["y"]])
        ex = transform_xy(alignment, ex)
        ax.plot(
            truth_trees["x"], truth_trees["y"], "o", mfc="none", mec="0.6", ms=4, label="true trees"
        )
        ax.plot(*ex[match >= 0].T, "g.", ms=4, label="matched trees")
        ax.plot(*ex[match < 0].T, "rx", ms=4, label="unmatched estimates")
    ax.set_aspect("equal")
    ax.set_title("top view (truth frame)")
    ax.legend(fontsize=7)
    ax = axes[0, 1]
    ax.plot(stamps - stamps[0], err)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error after alignment [m]")
    ax.set_title(f"ATE RMSE {np.sqrt(np.mean(err**2)):.3f} m")
    ax = axes[1, 0]
    ax2 = axes[1, 1]
    if trees is not None and est_trees is not None and truth_trees is not None:
        match = trees["match_est_to_truth"]
        ok = match >= 0
        td = truth_trees["dbh_m"][match[ok]]
        ed = est_trees["dbh_m"][ok]
        ax.plot(td * 100, ed * 100, ".", ms=4)
        lim = [0, max(np.nanmax(td * 100) if len(td) else 50, 10)]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set_xlabel("true DBH [cm]")
        ax.set_ylabel("estimated DBH [cm]")
        ax.set_title("DBH")
        ex = np.column_stack([est_trees["x"], est_trees["y"]])[ok]
        ex = transform_xy(alignment, ex)
        tx = np.column_stack([truth_trees["x"], truth_trees["y"]])[match[ok]]
        ax2.hist(np.linalg.norm(ex - tx, axis=1) * 100, bins=30)
        ax2.set_xlabel("tree position error [cm]")
        ax2.set_title("matched trees")
    else:
        ax.set_axis_off()
        ax2.set_axis_off()
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png"), mode="wb")
    plt.close(fig)
