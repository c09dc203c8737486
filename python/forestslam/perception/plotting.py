"""Top view of a breast-height slice with the detected stems drawn to DBH scale."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from forestslam.perception.stems import Stems


def breast_height_slice(
    points: np.ndarray, ground: np.ndarray, low_m: float = 1.0, high_m: float = 1.6
) -> np.ndarray:
    """Rows of points (N,3) whose height above the nearest ground point (XY) lies in
    [low_m, high_m]; all rows' heights are taken from `ground` (G,3)."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(ground) == 0 or len(points) == 0:
        return points[:0]
    _, j = cKDTree(ground[:, :2]).query(points[:, :2])
    h = points[:, 2] - ground[j, 2]
    return points[(h >= low_m) & (h <= high_m)]


def plot_detections(
    points: np.ndarray,
    stems: Stems,
    path: str | Path,
    title: str = "",
    truth_xy_dbh: np.ndarray | None = None,
) -> None:
    """PNG of the breast-height slice of `points` (N,3) with stem circles (DBH to scale, id
    labels); stems without an accepted DBH as crosses; optional truth (T,3) x, y, dbh dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    from forestslam.io.atomic import atomic_write

    sl = breast_height_slice(points, stems.ground)
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.scatter(sl[:, 0], sl[:, 1], s=1, c="0.5", lw=0, label="points 1.0-1.6 m above ground")
    if truth_xy_dbh is not None:
        for x, y, d in np.asarray(truth_xy_dbh).reshape(-1, 3):
            ax.add_patch(Circle((x, y), d / 2, fill=False, ls="--", ec="tab:blue", lw=0.8))
    for i in range(len(stems)):
        x, y = stems.xy[i]
        if np.isfinite(stems.dbh[i]):
            ax.add_patch(Circle((x, y), stems.dbh[i] / 2, fill=False, ec="tab:red", lw=1.2))
            label = f"{i}: {stems.dbh[i] * 100:.0f} cm"
        else:
            ax.plot(x, y, "x", c="tab:red")
            label = f"{i}"
        ax.annotate(label, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{len(stems)} stems (red: DBH to scale)")
    ax.legend(loc="upper right", fontsize=7, markerscale=8)
    fig.tight_layout()

    def write(f) -> None:
        fig.savefig(f, format="png", dpi=120)

    atomic_write(Path(path), write, "wb")
    plt.close(fig)
