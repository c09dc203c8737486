"""Figures of a run: map.png (trajectory and trees to DBH scale, drawn with Pillow) and dtm.png
(matplotlib)."""

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
    (the scale is chosen so stems stay visible on large maps and is stated in the legend).

    Drawn with Pillow: every run writes this figure, and matplotlib's import and text layout
    were ~0.5 s CPU of each run's end (a third of the final outputs)."""
    from forestslam.io.atomic import atomic_write

    canvas = _MapCanvas(trajectory_xy, odometry_xy, trees_xy)
    canvas.frame(title or f"{len(trees_xy)} trees", "x [m] (first scan's sensor frame)", "y [m]")
    pts = [p for p in (trajectory_xy, trees_xy) if len(p)]
    extent = float(np.ptp(np.vstack(pts), axis=0).max()) if pts else 1.0
    scale = max(1, int(round(extent / 15.0)))
    legend = []
    if odometry_xy is not None and len(odometry_xy):
        canvas.dashed_line(odometry_xy, (153, 153, 153), 1)
        legend.append(("line", (153, 153, 153), "odometry"))
    if len(trajectory_xy):
        canvas.line(trajectory_xy, _BLUE, 2)
        canvas.triangle(trajectory_xy[0], 6)
        legend += [("line", _BLUE, "SLAM trajectory"), ("start", (0, 0, 0), "start")]
    if len(trees_xy):
        d = np.where(np.isfinite(trees_dbh), trees_dbh, 0.1) * scale
        canvas.circles(trees_xy, d / 2)
        legend.append(("tree", _GREEN, f"trees (DBH x{scale})"))
    canvas.legend(legend)
    atomic_write(path, lambda f: canvas.image.save(f, format="PNG"), mode="wb")


_BLUE, _GREEN, _DARK_GREEN = (31, 119, 180), (44, 160, 44), (0, 100, 0)


class _MapCanvas:
    """A 960 x 960 px top view with equal axes over the given points, a grid with labelled ticks
    at 1-2-5 steps, and primitives in world coordinates."""

    SIZE, LEFT, RIGHT, TOP, BOTTOM = 960, 90, 25, 45, 70

    def __init__(self, *xy_sets) -> None:
        from PIL import Image, ImageDraw, ImageFont

        pts = [np.asarray(p, float).reshape(-1, 2) for p in xy_sets if p is not None and len(p)]
        pts = np.vstack(pts) if pts else np.zeros((1, 2))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = max(float((hi - lo).max()), 1.0) * 1.08  # margin for the tree circles
        self.centre = (lo + hi) / 2
        self.width = self.SIZE - self.LEFT - self.RIGHT
        self.height = self.SIZE - self.TOP - self.BOTTOM
        self.px_per_m = min(self.width, self.height) / span
        self.image = Image.new("RGB", (self.SIZE, self.SIZE), "white")
        self.draw = ImageDraw.Draw(self.image)
        self.font = ImageFont.load_default(13)

    def px(self, xy: np.ndarray) -> np.ndarray:
        """World (N,2) -> pixel (N,2) (y up)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        u = self.LEFT + self.width / 2 + (xy[:, 0] - self.centre[0]) * self.px_per_m
        v = self.TOP + self.height / 2 - (xy[:, 1] - self.centre[1]) * self.px_per_m
        return np.column_stack([u, v])

    def line(self, xy, colour, width: int) -> None:
        self.draw.line([tuple(p) for p in self.px(xy)], fill=colour, width=width, joint="curve")

    def dashed_line(self, xy, colour, width: int, dash_px: float = 6.0) -> None:
        """Dashes of dash_px along the path (every other one drawn)."""
        p = self.px(xy)
        if len(p) < 2:
            return
        along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
        edges = np.arange(0.0, along[-1] + dash_px, dash_px)
        cuts = np.column_stack([np.interp(edges, along, p[:, k]) for k in range(2)])
        for a, b in zip(cuts[:-1:2], cuts[1::2], strict=False):
            self.draw.line([tuple(a), tuple(b)], fill=colour, width=width)

    def triangle(self, xy, r: float) -> None:
        u, v = self.px(xy)[0]
        self.draw.polygon([(u, v - r), (u - r, v + r), (u + r, v + r)], fill=(0, 0, 0))

    def circles(self, xy, radius_m: np.ndarray) -> None:
        for (u, v), r in zip(self.px(xy), np.maximum(radius_m * self.px_per_m, 1.5), strict=True):
            self.draw.ellipse([u - r, v - r, u + r, v + r], fill=_GREEN, outline=_DARK_GREEN)

    def frame(self, title: str, xlabel: str, ylabel: str) -> None:
        """Axes box, light grid lines with tick labels, title and axis labels."""
        box = (self.LEFT, self.TOP, self.LEFT + self.width, self.TOP + self.height)
        half = np.array([self.width, self.height]) / 2 / self.px_per_m
        step = _nice_step(2 * half.max() / 7)
        digits = max(0, -int(np.floor(np.log10(step))))
        for axis in (0, 1):
            lo, hi = self.centre[axis] - half[axis], self.centre[axis] + half[axis]
            for t in np.arange(np.ceil(lo / step), np.floor(hi / step) + 1) * step:
                text = f"{t:.{digits}f}"
                if axis == 0:
                    u = self.px([[t, self.centre[1]]])[0, 0]
                    self.draw.line([(u, box[1]), (u, box[3])], fill=(225, 225, 225))
                    self.draw.text((u, box[3] + 6), text, fill="black", font=self.font, anchor="mt")
                else:
                    v = self.px([[self.centre[0], t]])[0, 1]
                    self.draw.line([(box[0], v), (box[2], v)], fill=(225, 225, 225))
                    self.draw.text((box[0] - 6, v), text, fill="black", font=self.font, anchor="rm")
        self.draw.rectangle(box, outline="black")
        mid_u = (box[0] + box[2]) / 2
        self.draw.text((mid_u, 14), title, fill="black", font=self.font, anchor="mt")
        self.draw.text((mid_u, self.SIZE - 22), xlabel, fill="black", font=self.font, anchor="mm")
        # above the y axis: the tick labels of georeferenced maps are 7 digits wide
        self.draw.text((box[0], box[1] - 6), ylabel, fill="black", font=self.font, anchor="rb")

    def legend(self, entries: list[tuple[str, tuple, str]]) -> None:
        if not entries:
            return
        u, v = self.LEFT + 10, self.TOP + 10
        w = 40 + max(self.draw.textlength(text, font=self.font) for _, _, text in entries)
        self.draw.rectangle([u, v, u + w, v + 20 * len(entries) + 6], fill="white", outline="gray")
        for k, (kind, colour, text) in enumerate(entries):
            y = v + 13 + 20 * k
            if kind == "line":
                self.draw.line([(u + 6, y), (u + 28, y)], fill=colour, width=2)
            elif kind == "start":
                self.draw.polygon([(u + 17, y - 5), (u + 12, y + 5), (u + 22, y + 5)], fill=colour)
            else:
                self.draw.ellipse([u + 12, y - 5, u + 22, y + 5], fill=colour, outline=_DARK_GREEN)
            self.draw.text((u + 34, y), text, fill="black", font=self.font, anchor="lm")


def _nice_step(raw: float) -> float:
    """The 1-2-5 x 10^k step at or above `raw`."""
    exp = 10.0 ** np.floor(np.log10(max(raw, 1e-9)))
    return float(next(m * exp for m in (1, 2, 5, 10) if m * exp >= raw))


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
