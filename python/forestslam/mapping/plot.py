"""Figures of a run: map.png (trajectory and trees to DBH scale) and dtm.png."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _subplots(figsize: tuple[float, float], dpi: int):
    """A figure and its axes on the Agg canvas, without pyplot (whose import and global figure
    manager cost about as much CPU as drawing the map; nothing here is shown on screen)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def plot_map(
    path: Path,
    trajectory_xy: np.ndarray,
    odometry_xy: np.ndarray | None,
    trees_xy: np.ndarray,
    trees_dbh: np.ndarray,
    title: str = "",
) -> None:
    """Top view: optimised trajectory, odometry, trees as circles of diameter DBH x `scale`
    (the scale is chosen so stems stay visible on large maps and is stated in the legend)."""
    from matplotlib.collections import EllipseCollection

    from forestslam.io.atomic import atomic_write

    fig, ax = _subplots((8, 8), 120)
    pts = [p for p in (trajectory_xy, trees_xy) if len(p)]
    extent = float(np.ptp(np.vstack(pts), axis=0).max()) if pts else 1.0
    scale = max(1, int(round(extent / 15.0)))
    if odometry_xy is not None and len(odometry_xy):
        ax.plot(*odometry_xy.T, color="0.6", lw=0.8, ls="--", label="odometry")
    if len(trajectory_xy):
        ax.plot(*trajectory_xy.T, color="tab:blue", lw=1.2, label="SLAM trajectory")
        ax.plot(*trajectory_xy[0], "k^", ms=6, label="start")
    if len(trees_xy):
        d = np.where(np.isfinite(trees_dbh), trees_dbh, 0.1) * scale
        coll = EllipseCollection(
            d,
            d,
            np.zeros(len(d)),
            units="xy",
            offsets=trees_xy,
            transOffset=ax.transData,
            facecolors="tab:green",
            edgecolors="darkgreen",
            alpha=0.8,
        )
        ax.add_collection(coll)
        ax.plot([], [], "o", color="tab:green", label=f"trees (DBH x{scale})")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m] (first scan's sensor frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{len(trees_xy)} trees")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png"), mode="wb")


def plot_dtm(path: Path, dtm: dict) -> None:
    from forestslam.io.atomic import atomic_write

    z = dtm["z"]
    fig, ax = _subplots((7, 6), 110)
    if z.size:
        c = dtm["cell_m"]
        ext = [
            dtm["x0"] - c / 2,
            dtm["x0"] + (z.shape[1] - 0.5) * c,
            dtm["y0"] - c / 2,
            dtm["y0"] + (z.shape[0] - 0.5) * c,
        ]
        finite = z[np.isfinite(z)]
        lo, hi = np.percentile(finite, [2, 98]) if finite.size else (0.0, 1.0)
        im = ax.imshow(z, origin="lower", extent=ext, cmap="terrain", vmin=lo, vmax=hi)
        fig.colorbar(im, ax=ax, label="ground height [m]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"DTM ({dtm['cell_m']} m cells)")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png"), mode="wb")
