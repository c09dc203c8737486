"""The forest model: stems, dead branches, crowns, shrubs and logs as analytic primitives for the
C++ ray caster, plus the tree truth table.

Truth: `x, y` is the stem axis at breast height (1.3 m above `z_ground`), `z_ground` the terrain
height where the axis meets the ground, `dbh_m` the mean of the two axes of the (elliptical,
smooth) stem section 1.3 m above `z_ground`. Bark roughness is zero-mean around the section.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from forestslam.sim.config import ClutterConfig, StemConfig
from forestslam.sim.stand import Stand
from forestslam.sim.terrain import Terrain

BREAST_HEIGHT_M = 1.3
SURFACES = ("none", "ground", "stem", "branch", "foliage", "shrub", "log")
GROUND, STEM, BRANCH, FOLIAGE, SHRUB, LOG = 1, 2, 3, 4, 5, 6


@dataclass
class Forest:
    stems: np.ndarray  # (K,12) see _core.SimScene
    cylinders: np.ndarray  # (M,8)
    foliage: np.ndarray  # (F,8)
    trees: dict[str, np.ndarray]  # truth columns id,x,y,z_ground,dbh_m,height_m

    def counts(self) -> dict[str, int]:
        return {
            "trees": int(len(self.stems)),
            "branches": int((self.cylinders[:, 7] == BRANCH).sum()),
            "logs": int((self.cylinders[:, 7] == LOG).sum()),
            "crown_clumps": int((self.foliage[:, 7] == FOLIAGE).sum()),
            "shrubs": int((self.foliage[:, 7] == SHRUB).sum()),
        }


def _path_distance(path_xy: np.ndarray | None, pts: np.ndarray) -> np.ndarray:
    """XY distance from pts (N,2) to the densely sampled path (inf when there is no path)."""
    if path_xy is None or len(path_xy) == 0 or len(pts) == 0:
        return np.full(len(pts), np.inf)
    from scipy.spatial import cKDTree

    return cKDTree(path_xy).query(pts)[0]


def build_stems(stand: Stand, terrain: Terrain, cfg: StemConfig, rng: np.random.Generator):
    n = len(stand)
    r = stand.dbh / 2.0
    e = rng.uniform(0.0, cfg.max_ellipticity, n)
    angle = rng.uniform(0.0, np.pi, n)
    lean = np.radians(cfg.max_lean_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    lean_dir = rng.uniform(0.0, 2 * np.pi, n)
    shear = np.tan(lean)[:, None] * np.column_stack([np.cos(lean_dir), np.sin(lean_dir)])
    base_xy = stand.xy - shear * BREAST_HEIGHT_M
    z_ground = terrain.height_at(base_xy)
    height = stand.height
    # Relative taper: radius loses taper/2 per metre, but keeps >= 25 % of r_bh at the top.
    k = (cfg.taper_m_per_m / 2.0) / r
    k = np.minimum(k, 0.75 / np.maximum(height - BREAST_HEIGHT_M, 0.5))
    bark = np.minimum(cfg.bark_amplitude_m, 0.1 * r)
    stems = np.column_stack(
        [
            base_xy,
            z_ground,
            shear,
            r * (1 + e),
            r * (1 - e),
            angle,
            k,
            np.full(n, -cfg.buried_m),
            height,
            bark,
        ]
    )
    trees = {
        "id": np.arange(n, dtype=np.int64),
        "x": stand.xy[:, 0].copy(),
        "y": stand.xy[:, 1].copy(),
        "z_ground": z_ground,
        "dbh_m": stems[:, 5] + stems[:, 6],
        "height_m": height.copy(),
    }
    return stems, trees


def _axis_xy(stems: np.ndarray, idx: np.ndarray, h: np.ndarray) -> np.ndarray:
    return stems[idx, 0:2] + stems[idx, 3:5] * h[:, None]


def build_branches(stems, cfg: ClutterConfig, crown_base, path_xy, rng) -> np.ndarray:
    counts = rng.poisson(cfg.branches_per_tree, len(stems))
    idx = np.repeat(np.arange(len(stems)), counts)
    m = len(idx)
    if m == 0:
        return np.zeros((0, 8))
    top = np.minimum(cfg.branch_height_m[1], crown_base[idx])
    h = rng.uniform(0.0, 1.0, m) * np.maximum(top - cfg.branch_height_m[0], 0.0)
    h += cfg.branch_height_m[0]
    az = rng.uniform(0, 2 * np.pi, m)
    el = np.radians(rng.uniform(-20.0, 35.0, m))
    length = rng.uniform(*cfg.branch_length_m, m)
    r_bh = 0.25 * (stems[idx, 5] + stems[idx, 6])
    radius = np.minimum(rng.uniform(*cfg.branch_radius_m, m), 0.4 * r_bh)
    start = np.column_stack([_axis_xy(stems, idx, h), stems[idx, 2] + h])
    direction = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    end = start + length[:, None] * direction
    cyl = np.column_stack([start, end, radius, np.full(m, BRANCH)])
    mid = 0.5 * (start[:, :2] + end[:, :2])
    near = np.minimum(_path_distance(path_xy, end[:, :2]), _path_distance(path_xy, mid))
    return cyl[near > cfg.path_clearance_m]


def build_crowns(stems, cfg: ClutterConfig, rng):
    n = len(stems)
    height = stems[:, 10]
    crown_base = rng.uniform(*cfg.crown_base_fraction, n) * height
    n_clumps = max(1, int(cfg.crown_clumps))
    idx = np.repeat(np.arange(n), n_clumps)
    length = (height - crown_base)[idx]
    radius = (cfg.crown_radius_fraction * height)[idx]
    radius = np.maximum(radius, 0.5)
    u = rng.uniform(0.2, 0.85, len(idx))
    hz = crown_base[idx] + u * length
    # Clumps spread around the axis, wider low in the crown (conical envelope).
    spread = 0.45 * radius * (1.0 - 0.6 * u)
    az = rng.uniform(0, 2 * np.pi, len(idx))
    centre_xy = _axis_xy(stems, idx, hz) + spread[:, None] * np.column_stack(
        [np.cos(az), np.sin(az)]
    )
    rh = radius * rng.uniform(0.45, 0.7, len(idx)) * (1.0 - 0.4 * u)
    rz = length * rng.uniform(0.2, 0.35, len(idx))
    foliage = np.column_stack(
        [
            centre_xy,
            stems[idx, 2] + hz,
            rh,
            rh * rng.uniform(0.85, 1.15, len(idx)),
            np.maximum(rz, 0.3),
            np.full(len(idx), cfg.foliage_sigma_per_m),
            np.full(len(idx), FOLIAGE),
        ]
    )
    return foliage, crown_base


def build_shrubs(stand, terrain, cfg: ClutterConfig, path_xy, rng) -> np.ndarray:
    x0, y0, x1, y1 = stand.bounds
    n = rng.poisson(cfg.shrubs_per_ha * (x1 - x0) * (y1 - y0) / 1e4)
    if n == 0:
        return np.zeros((0, 8))
    xy = rng.uniform((x0, y0), (x1, y1), (n, 2))
    r = rng.uniform(*cfg.shrub_radius_m, n)
    h = rng.uniform(*cfg.shrub_height_m, n)
    z = terrain.height_at(xy) + 0.4 * h
    shrubs = np.column_stack(
        [xy, z, r, r * rng.uniform(0.8, 1.2, n), h / 2, np.full(n, cfg.shrub_sigma_per_m)]
    )
    shrubs = np.column_stack([shrubs, np.full(n, SHRUB)])
    keep = _path_distance(path_xy, xy) > r * 1.2 + cfg.path_clearance_m
    return shrubs[keep]


def build_logs(stand, terrain, stems, cfg: ClutterConfig, path_xy, rng) -> np.ndarray:
    x0, y0, x1, y1 = stand.bounds
    n = rng.poisson(cfg.logs_per_ha * (x1 - x0) * (y1 - y0) / 1e4)
    if n == 0:
        return np.zeros((0, 8))
    centre = rng.uniform((x0, y0), (x1, y1), (n, 2))
    az = rng.uniform(0, np.pi, n)
    length = rng.uniform(*cfg.log_length_m, n)
    radius = rng.uniform(*cfg.log_radius_m, n)
    half = 0.5 * length[:, None] * np.column_stack([np.cos(az), np.sin(az)])
    a, b = centre - half, centre + half
    za = terrain.height_at(a) + 0.8 * radius
    zb = terrain.height_at(b) + 0.8 * radius
    logs = np.column_stack([a, za, b, zb, radius, np.full(n, LOG)])
    # Keep logs clear of the path and of standing stems (sampled along each log).
    s = np.linspace(0.0, 1.0, 25)
    samples = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]
    flat = samples.reshape(-1, 2)
    d_path = _path_distance(path_xy, flat).reshape(n, -1).min(axis=1)
    keep = d_path > radius + cfg.path_clearance_m
    if len(stems):
        from scipy.spatial import cKDTree

        d_stem, j = cKDTree(stems[:, :2]).query(flat)
        gap = d_stem - 0.5 * (stems[j, 5] + stems[j, 6]) - np.repeat(radius, len(s))
        keep &= gap.reshape(n, -1).min(axis=1) > 0.1
    return logs[keep]


def build_forest(
    stand: Stand,
    terrain: Terrain,
    stem_cfg: StemConfig,
    clutter: ClutterConfig,
    path_xy: np.ndarray | None,
    seed: int,
) -> Forest:
    """All primitives of the scene. Each component draws from its own random stream."""
    stems, trees = build_stems(stand, terrain, stem_cfg, np.random.default_rng([seed, 201]))
    foliage, crown_base = build_crowns(stems, clutter, np.random.default_rng([seed, 202]))
    branches = build_branches(
        stems, clutter, crown_base, path_xy, np.random.default_rng([seed, 203])
    )
    shrubs = build_shrubs(stand, terrain, clutter, path_xy, np.random.default_rng([seed, 204]))
    logs = build_logs(stand, terrain, stems, clutter, path_xy, np.random.default_rng([seed, 205]))
    if len(stems) == 0:
        foliage = np.zeros((0, 8))
    return Forest(
        stems=np.ascontiguousarray(stems.reshape(-1, 12)),
        cylinders=np.ascontiguousarray(np.vstack([branches, logs]).reshape(-1, 8)),
        foliage=np.ascontiguousarray(np.vstack([foliage.reshape(-1, 8), shrubs])),
        trees=trees,
    )
