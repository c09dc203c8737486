"""Plot figures of MLS-to-TLS mapping (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SLICE_PIXEL_M = 0.04  # raster cell of the breast-height slice (a stem wall is a few pixels)


def _figure(figsize, **subplot_kw):
    """A headless figure (Agg canvas, no pyplot: its import and state are not needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(**subplot_kw)


def slice_raster(points: np.ndarray, pixel_m: float = SLICE_PIXEL_M):
    """Occupancy raster of points (N,3) seen from above -> (image (H,W) bool, extent
    [xmin, xmax, ymin, ymax]) with image[0] at ymin: one vectorized pass instead of drawing
    every point (a scatter of 10^5 points cost seconds)."""
    lo = np.floor(points[:, :2].min(axis=0) / pixel_m) * pixel_m
    ij = np.floor((points[:, :2] - lo) / pixel_m).astype(np.int64)
    w, h = ij.max(axis=0) + 1
    image = np.zeros((h, w), dtype=bool)
    image[ij[:, 1], ij[:, 0]] = True
    extent = [lo[0], lo[0] + w * pixel_m, lo[1], lo[1] + h * pixel_m]
    return image, extent


def plot_tls_run(
    path: str | Path,
    map_points: np.ndarray,
    trees_xyz: np.ndarray,
    dbh_m: np.ndarray,
    coverage_tls: np.ndarray,
    coverage_merged: np.ndarray,
    poses: np.ndarray,
    base_z: np.ndarray | None = None,
    title: str = "MLS + TLS plot",
) -> None:
    """Top view: breast-height slice of the merged cloud (an occupancy raster), stems with DBH
    circles coloured by merged coverage, MLS trajectory; right: coverage TLS alone vs merged
    per stem."""
    from matplotlib import colormaps
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Circle

    fig, (ax, bx) = _figure((13, 6), ncols=2, gridspec_kw={"width_ratios": [3, 2]})
    pts = np.asarray(map_points).reshape(-1, 3)
    if len(pts):
        if base_z is not None and len(base_z):
            ref = float(np.median(base_z))
            band = pts[(pts[:, 2] > ref + 1.0) & (pts[:, 2] < ref + 1.6)]
        else:
            band = pts[np.abs(pts[:, 2] - np.median(pts[:, 2])) < 0.3]
        if len(band):
            image, extent = slice_raster(band)
            grey = ListedColormap([(1, 1, 1, 0), (0.55, 0.55, 0.55, 1)])
            ax.imshow(image, extent=extent, origin="lower", cmap=grey, interpolation="nearest")
            ax.plot([], [], "s", color="0.55", ms=3, label="slice")
    # One collection for all stems: adding a patch per stem re-computed the data limits each
    # time (0.4 s for 120 stems).
    ok = np.isfinite(dbh_m)
    if ok.any():
        circles = [Circle(c, 0.5 * d) for c, d in zip(trees_xyz[ok, :2], dbh_m[ok], strict=True)]
        colours = colormaps["viridis"](np.asarray(coverage_merged)[ok])
        ax.add_collection(PatchCollection(circles, facecolors="none", edgecolors=colours, lw=1.5))
    if len(poses):
        ax.plot(poses[:, 0, 3], poses[:, 1, 3], "r-", lw=0.8, label="MLS trajectory")
    ax.plot([0], [0], "k^", label="TLS station")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    order = np.argsort(coverage_tls)
    bx.plot(
        coverage_tls[order] * 100,
        "o-",
        ms=3,
        label=f"TLS alone (mean {coverage_tls.mean():.0%})" if len(order) else "TLS alone",
    )
    bx.plot(
        coverage_merged[order] * 100,
        "o-",
        ms=3,
        label=f"merged (mean {coverage_merged.mean():.0%})" if len(order) else "merged",
    )
    bx.set_xlabel("stem (sorted by TLS coverage)")
    bx.set_ylabel("circumference covered at breast height (%)")
    bx.set_ylim(0, 105)
    bx.legend()
    # Fixed margins for this fixed layout (tight_layout measured every text: 0.8 s); fast PNG
    # compression (the default level took most of savefig's time; the file is ~30 % larger).
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.09, top=0.95, wspace=0.18)
    fig.savefig(path, dpi=120, pil_kwargs={"compress_level": 1})


def plot_breast_height_slice(
    path: str | Path,
    points: np.ndarray,
    trees_xyz: np.ndarray,
    dbh_m: np.ndarray,
    base_z: np.ndarray,
    title: str,
) -> None:
    """Breast-height slice (1.2-1.4 m above each stem's ground) with fitted circles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    pts = np.asarray(points).reshape(-1, 3)
    ref = float(np.median(base_z)) if len(base_z) else float(np.percentile(pts[:, 2], 2))
    band = pts[(pts[:, 2] > ref + 1.1) & (pts[:, 2] < ref + 1.5)]
    ax.scatter(band[:, 0], band[:, 1], s=0.3, c="0.5", linewidths=0)
    for k in range(len(trees_xyz)):
        ax.add_patch(plt.Circle(trees_xyz[k, :2], 0.5 * dbh_m[k], fill=False, color="r", lw=1.2))
        ax.annotate(f"{k}: {dbh_m[k] * 100:.1f} cm", trees_xyz[k, :2], fontsize=7)
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
