"""Stands: tree positions, DBH and heights from a stem-map CSV, a crop of it, or a point process."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.config import StandConfig

log = logging.getLogger(__name__)


@dataclass
class Stand:
    """Trees of a stand, world frame: xy (N,2) stem centre at breast height, dbh (N,) m,
    height (N,) m. `bounds` = (xmin, ymin, xmax, ymax) of the stand area."""

    xy: np.ndarray
    dbh: np.ndarray
    height: np.ndarray
    bounds: tuple[float, float, float, float]

    def __len__(self) -> int:
        return len(self.dbh)


def shared_stand_dirs() -> list[Path]:
    """Folders searched for stands given by name: $FORESTSLAM_DATA/stands, then ../shared/data
    relative to the repository and to the working directory."""
    dirs = []
    if os.environ.get("FORESTSLAM_DATA"):
        dirs.append(Path(os.environ["FORESTSLAM_DATA"]) / "stands")
    dirs.append(Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "stands")
    dirs.append(Path.cwd() / ".." / "shared" / "data" / "stands")
    return dirs


def resolve_stand_file(source: str) -> Path:
    path = Path(source)
    if path.suffix.lower() == ".csv" or path.is_file():
        if not path.is_file():
            raise InputError(f"{path}: stand CSV not found")
        return path
    for folder in shared_stand_dirs():
        candidate = folder / f"{source}.csv"
        if candidate.is_file():
            return candidate.resolve()
    raise InputError(
        f"stand {source!r}: not a CSV file and not found in "
        + ", ".join(str(d) for d in shared_stand_dirs())
        + " (use 'generated', a CSV with x,y,dbh_m[,height_m], or set FORESTSLAM_DATA)"
    )


def heights_from_dbh(dbh_m: np.ndarray, a: float, b: float) -> np.ndarray:
    """Naslund height curve h = 1.3 + (d / (a + b d))^2, d in cm."""
    d_cm = np.asarray(dbh_m, dtype=np.float64) * 100.0
    return 1.3 + (d_cm / (a + b * d_cm)) ** 2


def read_stand_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """CSV with header x,y,dbh_m[,height_m] (extra columns ignored) -> xy, dbh, height|None."""
    path = Path(path)
    try:
        data = np.genfromtxt(path, delimiter=",", names=True, dtype=np.float64, ndmin=1)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: cannot read stand CSV ({exc})") from exc
    names = data.dtype.names or ()
    missing = [c for c in ("x", "y", "dbh_m") if c not in names]
    if missing:
        raise InputError(f"{path}: stand CSV needs columns x,y,dbh_m; missing {missing}")
    xy = np.column_stack([data["x"], data["y"]]).astype(np.float64)
    dbh = np.asarray(data["dbh_m"], dtype=np.float64)
    height = np.asarray(data["height_m"], dtype=np.float64) if "height_m" in names else None
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(dbh) & (dbh > 0)
    if height is not None:
        ok &= np.isfinite(height) & (height > 1.5)
    if (~ok).any():
        log.warning("%s: skipped %d rows with missing or invalid values", path, int((~ok).sum()))
    return xy[ok], dbh[ok], None if height is None else height[ok]


def _thin_min_spacing(xy: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of a greedy subset whose points are at least `spacing` apart (first come first)."""
    from scipy.spatial import cKDTree

    if len(xy) == 0 or spacing <= 0:
        return np.arange(len(xy))
    pairs = cKDTree(xy).query_pairs(spacing, output_type="ndarray")
    keep = np.ones(len(xy), dtype=bool)
    # Greedy: process conflicts in index order; drop the later point of a pair whose earlier
    # point is still kept (a sequential inhibition process).
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    for i, j in pairs:  # conflicts only (few), not a per-point loop over the stand
        if keep[i] and keep[j]:
            keep[j] = False
    return np.flatnonzero(keep)


def generate_positions(cfg: StandConfig, rng: np.random.Generator) -> np.ndarray:
    w, h = (float(v) for v in cfg.size_m)
    if w <= 0 or h <= 0 or cfg.density_per_ha < 0:
        raise InputError("stand: size_m must be > 0 and density_per_ha >= 0")
    if cfg.density_per_ha == 0:
        return np.zeros((0, 2))  # an empty world (terrain and clutter only)
    n_target = cfg.density_per_ha * w * h / 1e4
    if cfg.process == "regular":
        step = np.sqrt(1e4 / cfg.density_per_ha)
        gx, gy = np.meshgrid(np.arange(step / 2, w, step), np.arange(step / 2, h, step))
        xy = np.column_stack([gx.ravel(), gy.ravel()])
        xy += rng.normal(0.0, 0.15 * step, xy.shape)
    elif cfg.process == "clustered":
        # Thomas process, oversampled so that thinning to min spacing keeps the density.
        n_parents = max(1, rng.poisson(2.0 * n_target / max(cfg.trees_per_cluster, 1.0)))
        parents = rng.uniform((0, 0), (w, h), (n_parents, 2))
        counts = rng.poisson(max(cfg.trees_per_cluster, 1.0), n_parents)
        xy = np.repeat(parents, counts, axis=0)
        xy += rng.normal(0.0, cfg.cluster_radius_m / 2.0, xy.shape)
    elif cfg.process == "poisson":
        xy = rng.uniform((0, 0), (w, h), (rng.poisson(2.0 * n_target), 2))
    else:
        raise InputError(
            f"stand.process must be clustered, regular or poisson, not {cfg.process!r}"
        )
    xy = xy[(xy[:, 0] >= 0) & (xy[:, 0] <= w) & (xy[:, 1] >= 0) & (xy[:, 1] <= h)]
    xy = xy[_thin_min_spacing(xy, cfg.min_spacing_m)]
    n_keep = min(len(xy), int(round(n_target)))
    return xy[rng.permutation(len(xy))[:n_keep]] if cfg.process != "regular" else xy


def generate_dbh(cfg: StandConfig, n: int, rng: np.random.Generator) -> np.ndarray:
    """Log-normal DBH with the given mean and standard deviation, clipped to [min, max]."""
    mean, std = cfg.dbh_mean_m, cfg.dbh_std_m
    if mean <= 0 or std < 0:
        raise InputError("stand: dbh_mean_m must be > 0 and dbh_std_m >= 0")
    s2 = np.log1p((std / mean) ** 2)
    d = rng.lognormal(np.log(mean) - s2 / 2, np.sqrt(s2), n)
    return np.clip(d, cfg.dbh_min_m, cfg.dbh_max_m)


def load_stand(
    source: str | Path | StandConfig = "generated",
    crop_m: tuple[float, float, float, float] | None = None,
    seed: int = 0,
    **generated: object,
) -> Stand:
    """A stand from a CSV file / shared stand name, optionally cropped to (xmin, ymin, xmax, ymax),
    or generated by a point process (`source='generated'`, parameters as in StandConfig)."""
    if isinstance(source, StandConfig):
        cfg = source
    else:
        cfg = StandConfig(source=str(source), crop_m=crop_m, **generated)  # type: ignore[arg-type]
    rng = np.random.default_rng([seed, 101])
    if cfg.source == "generated":
        xy = generate_positions(cfg, rng)
        dbh = generate_dbh(cfg, len(xy), rng)
        height = None
        bounds = (0.0, 0.0, float(cfg.size_m[0]), float(cfg.size_m[1]))
    else:
        xy, dbh, height = read_stand_csv(resolve_stand_file(cfg.source))
        if len(xy) == 0:
            raise InputError(f"stand {cfg.source}: no valid trees")
        bounds = (*(float(v) for v in xy.min(axis=0)), *(float(v) for v in xy.max(axis=0)))
    if cfg.crop_m is not None:
        x0, y0, x1, y1 = (float(v) for v in cfg.crop_m)
        if not (x1 > x0 and y1 > y0):
            raise InputError(f"stand crop {cfg.crop_m}: need xmin < xmax and ymin < ymax")
        keep = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        xy, dbh = xy[keep], dbh[keep]
        height = None if height is None else height[keep]
        bounds = (x0, y0, x1, y1)
    if height is None:
        height = heights_from_dbh(dbh, cfg.height_a, cfg.height_b)
        height *= np.exp(rng.normal(0.0, cfg.height_noise_rel, len(height)))
        height = np.maximum(height, 2.0)
    log.info("stand %s: %d trees over %s", cfg.source, len(dbh), bounds)
    return Stand(np.ascontiguousarray(xy), dbh.copy(), np.asarray(height, dtype=np.float64), bounds)
