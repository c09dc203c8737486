"""Preview PNG of a simulated run: top view (trees, path, one scan) and its breast-height slice."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from forestslam.io import Scan
from forestslam.io.atomic import atomic_write


def write_preview(world, scan: Scan, k: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    # The scan in the world frame (pose at each point's own time).
    t0 = float(world.stamps[min(k, len(world.stamps) - 1)])
    times = np.unique(scan.time) if scan.time is not None else np.zeros(1)
    poses = world.trajectory.poses(t0 + times)
    which = np.searchsorted(times, scan.time) if scan.time is not None else np.zeros(len(scan), int)
    world_pts = np.einsum("nij,nj->ni", poses[which, :3, :3], scan.points) + poses[which, :3, 3]
    above = world_pts[:, 2] - world.terrain.height_at(world_pts[:, :2])
    trees = world.forest.trees
    sensor_xy = poses[0, :2, 3]

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(14, 7))
    ax0.scatter(world_pts[:, 0], world_pts[:, 1], s=0.2, c=above, cmap="viridis", vmin=0, vmax=8)
    ax0.plot(world.path.xy[:, 0], world.path.xy[:, 1], "r-", lw=1, label="path")
    ax0.add_collection(
        PatchCollection(
            [
                Circle((x, y), max(d, 0.1) * 2)
                for x, y, d in zip(trees["x"], trees["y"], trees["dbh_m"], strict=True)
            ],
            facecolor="none",
            edgecolor="k",
            lw=0.5,
        )
    )
    ax0.plot(*sensor_xy, "r^", ms=10, label=f"sensor, scan {k}")
    ax0.set_title(f"{world.config.name}: top view (points coloured by height above ground, m)")
    ax0.set_aspect("equal")
    ax0.legend(loc="upper right")

    band = (above > 1.0) & (above < 1.6)
    rel = world_pts[band, :2] - sensor_xy
    ax1.scatter(rel[:, 0], rel[:, 1], s=1.0, c="g", label="points 1.0-1.6 m above ground")
    near = np.hypot(trees["x"] - sensor_xy[0], trees["y"] - sensor_xy[1]) < 25
    ax1.add_collection(
        PatchCollection(
            [
                Circle((x - sensor_xy[0], y - sensor_xy[1]), d / 2)
                for x, y, d in zip(
                    trees["x"][near], trees["y"][near], trees["dbh_m"][near], strict=True
                )
            ],
            facecolor="none",
            edgecolor="r",
            lw=0.8,
        )
    )
    ax1.set_xlim(-25, 25)
    ax1.set_ylim(-25, 25)
    ax1.set_aspect("equal")
    ax1.set_title("breast-height slice around the sensor (red: true stems at DBH)")
    ax1.legend(loc="upper right")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110), "wb")
    plt.close(fig)
