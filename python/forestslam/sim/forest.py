"""The forest model: stems, dead branches, crowns, shrubs and logs as analytic primitives for the
C++ ray caster, plus the tree truth table.

Stems are not analytic cylinders: elliptical (ovality), optionally polygonal, with low 2-3-5
lobes, bark roughness, taper, root flare, lean and sweep (a bowed axis: a chain of straight
segments), see sim::Stem.

Truth: `x, y` is the stem axis at breast height (1.3 m above `z_ground`), `z_ground` the terrain
height where the axis meets the ground, `dbh_m` the tape DBH of the actual horizontal section
1.3 m above `z_ground`, bark, lobes, polygon and flare included: the perimeter of its convex hull
(where a tape lies) / pi, which equals its mean caliper diameter over all directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.config import ClutterConfig, StemConfig
from forestslam.sim.stand import Stand
from forestslam.sim.terrain import Terrain

BREAST_HEIGHT_M = 1.3
SURFACES = ("none", "ground", "stem", "branch", "foliage", "shrub", "log")
GROUND, STEM, BRANCH, FOLIAGE, SHRUB, LOG = 1, 2, 3, 4, 5, 6


@dataclass
class TreeAxes:
    """Per tree: the stem axis and size. The axis leans (shear, m per m) and bows sideways
    (sweep: offset `bow` at mid height, a half sine over the tree's height)."""

    base: np.ndarray  # (n,3) axis at the ground (z = z_ground)
    shear: np.ndarray  # (n,2)
    bow: np.ndarray  # (n,2)
    height: np.ndarray  # (n,)
    radius_bh: np.ndarray  # (n,) truth DBH / 2

    def offset(self, idx: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Axis XY offset from the base at heights h (m above the base) of trees idx."""
        s = np.sin(np.pi * np.clip(h / self.height[idx], 0.0, 1.0))
        return self.shear[idx] * h[:, None] + self.bow[idx] * s[:, None]

    def axis_xy(self, idx: np.ndarray, h: np.ndarray) -> np.ndarray:
        return self.base[idx, :2] + self.offset(idx, h)


@dataclass
class Forest:
    stems: np.ndarray  # (K,18) stem segments, see _core.SimScene
    cylinders: np.ndarray  # (M,8)
    foliage: np.ndarray  # (F,8)
    trees: dict[str, np.ndarray]  # truth columns id,x,y,z_ground,dbh_m,height_m
    axes: TreeAxes

    def counts(self) -> dict[str, int]:
        return {
            "trees": int(len(self.trees["id"])),
            "stem_segments": int(len(self.stems)),
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


def girth_dbh(sections: np.ndarray) -> np.ndarray:
    """Tape DBH of sections (K,n,2): perimeter of the convex hull / pi, which is also the mean
    caliper diameter over all directions (Cauchy)."""
    from scipy.spatial import ConvexHull

    return np.array([ConvexHull(xy).area / np.pi for xy in sections])


def section_points(rows: np.ndarray, seed: int, h: np.ndarray, n: int = 2160) -> np.ndarray:
    """(K,n,2) world XY of the horizontal sections of stem rows (K,18) h (K,) above their base."""
    from forestslam import _core

    xy = _core.sim_stem_sections(np.ascontiguousarray(rows), int(seed), np.asarray(h, float), n)
    return np.asarray(xy).reshape(len(rows), n, 2)


def _knots(cfg: StemConfig, height: float) -> np.ndarray:
    """Segment ends of one stem: below the ground, 0.6 m and 2.2 m (breast height within one
    segment, the flare mostly below), then every segment_m up to the top."""
    inner = np.concatenate([[0.6, 2.2], 2.2 + cfg.segment_m * np.arange(1, 64)])
    inner = inner[inner < height - 0.3]
    return np.concatenate([[-cfg.buried_m], inner, [height]])


def _check(cfg: StemConfig) -> None:
    lo, hi = cfg.polygon_sides
    checks = (
        ((lo == 0 and hi == 0) or 3 <= lo <= hi, "polygon_sides (0, 0) or 3 <= lo <= hi"),
        (0 <= cfg.irregularity[0] <= cfg.irregularity[1] < 0.3, "0 <= irregularity < 0.3"),
        (0 <= cfg.flare[0] <= cfg.flare[1], "0 <= flare lo <= hi"),
        (0 < cfg.flare_height_m[0] <= cfg.flare_height_m[1], "0 < flare_height_m lo <= hi"),
        (0 <= cfg.max_ellipticity < 0.5, "0 <= max_ellipticity < 0.5"),
        (cfg.max_sweep_m_per_m >= 0 and cfg.segment_m > 0.5, "sweep >= 0, segment_m > 0.5"),
        (cfg.bark_amplitude_m >= 0 and cfg.buried_m >= 0, "bark and buried >= 0"),
    )
    bad = [what for ok, what in checks if not ok]
    if bad:
        raise InputError(f"stems: need {'; '.join(bad)}")


def build_stems(stand: Stand, terrain: Terrain, cfg: StemConfig, rng: np.random.Generator, seed=0):
    """Stem segments (K,18), the truth table and the tree axes. The semi-axes are scaled so
    that the tape DBH of the actual section at 1.3 m equals the stand's DBH (to < 0.01 mm); the
    truth is that measured girth, not a model parameter."""
    _check(cfg)
    n = len(stand)
    r = stand.dbh / 2.0
    e = rng.uniform(0.0, cfg.max_ellipticity, n)
    angle = rng.uniform(0.0, np.pi, n)
    lean = np.radians(cfg.max_lean_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    lean_dir = rng.uniform(0.0, 2 * np.pi, n)
    shear = np.tan(lean)[:, None] * np.column_stack([np.cos(lean_dir), np.sin(lean_dir)])
    height = stand.height
    bow_dir = rng.uniform(0.0, 2 * np.pi, n)
    bow = (rng.uniform(0.0, cfg.max_sweep_m_per_m, n) * height)[:, None] * np.column_stack(
        [np.cos(bow_dir), np.sin(bow_dir)]
    )
    lo, hi = cfg.polygon_sides
    sides = rng.integers(lo, hi + 1, n) if hi > 0 else np.zeros(n, dtype=np.int64)
    poly_angle = rng.uniform(0.0, 2 * np.pi, n)
    irregularity = rng.uniform(*cfg.irregularity, n)
    flare = rng.uniform(*cfg.flare, n)
    flare_h = rng.uniform(*cfg.flare_height_m, n)
    axes = TreeAxes(np.zeros((n, 3)), shear, bow, height.astype(float), r.copy())
    idx = np.arange(n)
    axes.base[:, :2] = stand.xy - axes.offset(idx, np.full(n, BREAST_HEIGHT_M))
    axes.base[:, 2] = terrain.height_at(axes.base[:, :2])
    # Relative taper: radius loses taper/2 per metre, but keeps >= 25 % of r_bh at the top.
    k = (cfg.taper_m_per_m / 2.0) / r
    k = np.minimum(k, 0.75 / np.maximum(height - BREAST_HEIGHT_M, 0.5))
    bark = np.minimum(cfg.bark_amplitude_m, 0.1 * r)
    rows, bh_row = [], np.zeros(n, dtype=np.int64)
    for i in range(n):
        h = _knots(cfg, height[i])
        off = axes.offset(np.full(len(h), i), h)
        slope = np.diff(off, axis=0) / np.diff(h)[:, None]
        vbase = axes.base[i, :2] + off[:-1] - slope * h[:-1, None]
        bh_row[i] = len(rows) + int(np.searchsorted(h, BREAST_HEIGHT_M) - 1)
        for j in range(len(h) - 1):
            rows.append(
                [*vbase[j], axes.base[i, 2], *slope[j], r[i] * (1 + e[i]), r[i] * (1 - e[i])]
                + [angle[i], k[i], h[j], h[j + 1], bark[i], i, flare[i], flare_h[i]]
                + [sides[i], poly_angle[i], irregularity[i]]
            )
    stems = np.asarray(rows, dtype=np.float64).reshape(-1, 18)
    if n:
        at_bh = np.full(n, BREAST_HEIGHT_M)
        tree = stems[:, 12].astype(np.int64)
        dbh = girth_dbh(section_points(stems[bh_row], seed, at_bh))
        for _ in range(2):  # the bark does not scale with the semi-axes: twice is < 0.01 mm
            stems[:, 5:7] *= (stand.dbh / dbh)[tree, None]
            dbh = girth_dbh(section_points(stems[bh_row], seed, at_bh))
    else:
        dbh = np.zeros(0)
    axes.radius_bh = dbh / 2.0
    trees = {
        "id": np.arange(n, dtype=np.int64),
        "x": stand.xy[:, 0].copy(),
        "y": stand.xy[:, 1].copy(),
        "z_ground": axes.base[:, 2].copy(),
        "dbh_m": dbh,
        "height_m": height.copy(),
    }
    return stems, trees, axes


def build_branches(axes: TreeAxes, cfg: ClutterConfig, crown_base, path_xy, rng) -> np.ndarray:
    counts = rng.poisson(cfg.branches_per_tree, len(axes.height))
    idx = np.repeat(np.arange(len(axes.height)), counts)
    m = len(idx)
    if m == 0:
        return np.zeros((0, 8))
    top = np.minimum(cfg.branch_height_m[1], crown_base[idx])
    h = rng.uniform(0.0, 1.0, m) * np.maximum(top - cfg.branch_height_m[0], 0.0)
    h += cfg.branch_height_m[0]
    az = rng.uniform(0, 2 * np.pi, m)
    el = np.radians(rng.uniform(-20.0, 35.0, m))
    length = rng.uniform(*cfg.branch_length_m, m)
    r_bh = axes.radius_bh[idx]
    radius = np.minimum(rng.uniform(*cfg.branch_radius_m, m), 0.4 * r_bh)
    start = np.column_stack([axes.axis_xy(idx, h), axes.base[idx, 2] + h])
    direction = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    end = start + length[:, None] * direction
    cyl = np.column_stack([start, end, radius, np.full(m, BRANCH)])
    mid = 0.5 * (start[:, :2] + end[:, :2])
    near = np.minimum(_path_distance(path_xy, end[:, :2]), _path_distance(path_xy, mid))
    return cyl[near > cfg.path_clearance_m]


def build_crowns(axes: TreeAxes, cfg: ClutterConfig, rng):
    n = len(axes.height)
    height = axes.height
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
    centre_xy = axes.axis_xy(idx, hz) + spread[:, None] * np.column_stack([np.cos(az), np.sin(az)])
    rh = radius * rng.uniform(0.45, 0.7, len(idx)) * (1.0 - 0.4 * u)
    rz = length * rng.uniform(0.2, 0.35, len(idx))
    foliage = np.column_stack(
        [
            centre_xy,
            axes.base[idx, 2] + hz,
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


def build_logs(stand, terrain, axes: TreeAxes, cfg, path_xy, rng) -> np.ndarray:
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
    if len(axes.height):
        from scipy.spatial import cKDTree

        d_stem, j = cKDTree(axes.base[:, :2]).query(flat)
        gap = d_stem - 1.5 * axes.radius_bh[j] - np.repeat(radius, len(s))
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
    """All primitives of the scene. Each component draws from its own random stream; seed also
    sets the bark and lobe phases (the SimScene must get the same)."""
    stems, trees, axes = build_stems(
        stand, terrain, stem_cfg, np.random.default_rng([seed, 201]), seed
    )
    foliage, crown_base = build_crowns(axes, clutter, np.random.default_rng([seed, 202]))
    branches = build_branches(
        axes, clutter, crown_base, path_xy, np.random.default_rng([seed, 203])
    )
    shrubs = build_shrubs(stand, terrain, clutter, path_xy, np.random.default_rng([seed, 204]))
    logs = build_logs(stand, terrain, axes, clutter, path_xy, np.random.default_rng([seed, 205]))
    if len(stems) == 0:
        foliage = np.zeros((0, 8))
    return Forest(
        stems=np.ascontiguousarray(stems.reshape(-1, 18)),
        cylinders=np.ascontiguousarray(np.vstack([branches, logs]).reshape(-1, 8)),
        foliage=np.ascontiguousarray(np.vstack([foliage.reshape(-1, 8), shrubs])),
        trees=trees,
        axes=axes,
    )
