"""Ground map and DTM against the simulator's true terrain.

A simulator truth directory carries the scenario (`scenario.yaml`), from which the terrain
heightfield is rebuilt exactly (same seed, same grid). The run's DTM cells (and ground points)
are moved by the trajectory alignment into the truth frame and compared with the terrain height
under them. Truth directories without a scenario (real data) have no terrain: the check is skipped.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from forestslam.geometry import transform_points

log = logging.getLogger(__name__)


def load_truth_terrain(truth_dir: str | Path):
    """The true terrain (forestslam.sim.terrain.Terrain) of a simulator truth directory, or None
    when the directory has no scenario.yaml or the scenario cannot be rebuilt (logged)."""
    path = Path(truth_dir) / "scenario.yaml"
    if not path.is_file():
        return None
    from forestslam.sim.scenarios import load_scenario
    from forestslam.sim.world import build_world

    try:
        return build_world(load_scenario(path)).terrain
    except Exception as exc:  # a truth from another simulator version: skip, do not fail the run
        log.warning("%s: terrain not rebuilt (%s); ground not evaluated", path, exc)
        return None


def dtm_cells(dtm_path: str | Path) -> np.ndarray:
    """(K,3) centre x, y and height of every defined cell of a run's dtm.npz (estimate frame)."""
    with np.load(dtm_path) as d:
        z, x0, y0, cell = d["z"], float(d["x0"]), float(d["y0"]), float(d["cell_m"])
    r, c = np.nonzero(np.isfinite(z))
    return np.column_stack([x0 + c * cell, y0 + r * cell, z[r, c]])


def vertical_errors(points_world: np.ndarray, terrain) -> np.ndarray:
    """z minus the terrain height under each point (K,3) of the truth frame; finite ones only."""
    points_world = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    dz = points_world[:, 2] - terrain.height_at(points_world[:, :2])
    return dz[np.isfinite(dz)]


def height_errors(points: np.ndarray, alignment: np.ndarray, terrain) -> dict:
    """Vertical errors of points (K,3) in the estimate frame, moved by `alignment` (4,4)
    estimate -> truth, against the terrain: n, median_abs_m, bias_m (median signed), rmse_m,
    p90_abs_m (None when there are no points)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dz = vertical_errors(transform_points(alignment, points), terrain)
    if len(dz) == 0:
        return {"n": 0, "median_abs_m": None, "bias_m": None, "rmse_m": None, "p90_abs_m": None}
    return {
        "n": int(len(dz)),
        "median_abs_m": float(np.median(np.abs(dz))),
        "bias_m": float(np.median(dz)),
        "rmse_m": float(np.sqrt(np.mean(dz**2))),
        "p90_abs_m": float(np.percentile(np.abs(dz), 90)),
    }
