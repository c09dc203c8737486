"""Stem worlds for DBH tests and bench/dbh_bench.py, independent of forestslam.sim.

Stems are vertical prisms over a cross-section polygon: round (a 256-gon), or polygonal
(7-14 sides) with bark roughness on the vertices, ovality 0-10 % at a random orientation. Each
beam of a spinning profile is cast exactly against the polygons (first hit, occlusion between
stems) and a flat ground. Range noise, dropout and one of two intensity models:
  - "flat": constant bark / ground intensity well under the filter threshold (what the
    project's simulator effectively does);
  - "lambert": reflectance x cos(incidence)^0.7 with a range fall-off and 15 % speckle; bark
    and foliage distributions overlap a little, and scaled by an unknown sensor gain, so the
    profile's threshold cuts into the bark returns facing the sensor (bright) and keeps the
    grazing ones (dark). Its reflectance was chosen against the threshold (100);
  - "material": independent of the threshold: per-material log-normal reflectance (bark median
    70, ground 40: no sensor units in common with the filter), one draw per stem (sigma 0.35)
    and one per return (sigma 0.3), cos(incidence) and a (8 m / range)^0.5 fall-off beyond 8 m.
Truth DBH = perimeter / pi (the girth tape; for a convex section also its mean caliper width).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from forestslam.io.scan import Scan
from forestslam.sensors import load_profile


@dataclass(frozen=True)
class StemStyle:
    name: str
    sides: tuple[int, int] = (0, 0)  # polygon sides drawn in [lo, hi]; 0 = round
    bark_m: float = 0.0  # vertex radius noise (std)
    ovality: tuple[float, float] = (0.0, 0.0)  # (a - b) / (a + b) drawn in [lo, hi]
    intensity: str = "flat"
    gain: tuple[float, float] = (1.0, 1.0)  # sensor intensity gain drawn per world


ROUND = StemStyle("round")
ROUGH = StemStyle(
    "rough", sides=(7, 14), bark_m=0.005, ovality=(0.0, 0.10), intensity="lambert", gain=(1.0, 1.6)
)
# The rough stems under the second intensity model (see the module's docstring).
ROUGH_MATERIAL = StemStyle(
    "rough-m", sides=(7, 14), bark_m=0.005, ovality=(0.0, 0.10), intensity="material"
)


@dataclass
class Stem:
    x: float
    y: float
    polygon: np.ndarray  # (V,2) vertices relative to (x, y), counter-clockwise

    @property
    def dbh(self) -> float:
        edges = np.roll(self.polygon, -1, axis=0) - self.polygon
        return float(np.linalg.norm(edges, axis=1).sum() / np.pi)

    @property
    def r_max(self) -> float:
        return float(np.linalg.norm(self.polygon, axis=1).max())


def make_stem(x: float, y: float, dbh: float, style: StemStyle, rng) -> Stem:
    sides = 256 if style.sides[1] == 0 else int(rng.integers(style.sides[0], style.sides[1] + 1))
    a = (
        np.sort(rng.uniform(0, 2 * np.pi, sides))
        if sides < 256
        else np.linspace(0, 2 * np.pi, sides, False)
    )
    if sides < 256:  # irregular polygon: vertex angles jittered around even spacing
        a = (
            np.linspace(0, 2 * np.pi, sides, False)
            + rng.uniform(-0.3, 0.3, sides) * (2 * np.pi / sides)
            + rng.uniform(0, 2 * np.pi)
        )
    ov = rng.uniform(*style.ovality)
    phi = rng.uniform(0, np.pi)
    r = 0.5 * dbh * (1 + ov * np.cos(2 * (a - phi))) + rng.normal(0, style.bark_m, sides)
    poly = np.c_[r * np.cos(a), r * np.sin(a)]
    stem = Stem(x, y, poly)
    stem.polygon *= dbh / stem.dbh  # truth DBH exactly `dbh`
    return stem


def make_world(
    style: StemStyle,
    seed: int,
    n: int = 40,
    length_m: float = 40.0,
    lane_m: float = 2.5,
    depth_m: float = 12.0,
) -> list[Stem]:
    """Stems on both sides of a straight lane along x in [0, length_m] (none within lane_m of
    the lane), DBH 0.12-0.5 m, at least 1.5 m apart."""
    rng = np.random.default_rng(seed)
    out: list[Stem] = []
    for _ in range(100 * n):
        if len(out) == n:
            break
        x = rng.uniform(-5, length_m + 5)
        y = rng.choice([-1, 1]) * rng.uniform(lane_m, depth_m)
        if any(np.hypot(x - s.x, y - s.y) < 1.5 for s in out):
            continue
        out.append(make_stem(x, y, rng.uniform(0.12, 0.5), style, rng))
    return out


def _ray_polygon(o: np.ndarray, u: np.ndarray, poly: np.ndarray):
    """Distance along unit 2D rays u (M,2) from o (2,) to the polygon (V,2) boundary (first
    crossing, inf if none) and the edge index hit."""
    p0 = poly
    e = np.roll(poly, -1, axis=0) - poly  # (V,2)
    w = p0 - o  # (V,2)
    den = u[:, None, 0] * e[None, :, 1] - u[:, None, 1] * e[None, :, 0]  # (M,V)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        s = (w[None, :, 0] * u[:, None, 1] - w[None, :, 1] * u[:, None, 0]) / den
    ok = (t > 0) & (s >= 0) & (s <= 1) & np.isfinite(t)
    t = np.where(ok, t, np.inf)
    k = np.argmin(t, axis=1)
    return t[np.arange(len(u)), k], k, e


def scan_stems(
    stems: list[Stem],
    sensor_xy: np.ndarray,
    style: StemStyle,
    sensor: str = "vlp16",
    sensor_height_m: float = 1.8,
    noise_m: float | None = None,
    seed: int = 0,
    gain: float = 1.0,
    footprint_rad: float = 0.0,
) -> Scan:
    """One scan from sensor_xy (sensor frame = world shifted, no rotation). `footprint_rad`:
    half the beam divergence; a beam returns from a stem when any part of its footprint meets
    it (the worst case of a real beam's partly hit edges, which widen a silhouette by up to
    range x divergence), at the range of the nearest part met."""
    profile = load_profile(sensor)
    rng = np.random.default_rng(seed)
    noise = profile.range_noise_m if noise_m is None else noise_m
    el = profile.vertical_angles_rad
    n_az = profile.image_cols
    az = -np.pi + (np.arange(n_az) + rng.uniform()) * 2 * np.pi / n_az
    ring = np.repeat(np.arange(len(el)), n_az)
    e, a = el[ring], np.tile(az, len(el))
    u = np.c_[np.cos(a), np.sin(a)]
    t_xy = np.full(len(a), np.inf)  # horizontal distance of the first hit
    kind = np.zeros(len(a), np.int8)  # 1 ground, 2 stem
    obj = np.full(len(a), 1.0)  # per-object reflectance factor (material model)
    cos_inc = np.ones(len(a))
    down = e < 0
    t_xy[down] = sensor_height_m / np.tan(-e[down])
    kind[down] = 1
    cos_inc[down] = np.sin(-e[down])
    for st in stems:
        key = [int(abs(st.x) * 1e3), int(abs(st.y) * 1e3)]  # one draw per stem, every scan
        factor = np.random.default_rng(key).lognormal(0.0, 0.35)
        c = np.array([st.x, st.y]) - sensor_xy
        d = np.hypot(*c)
        if d - st.r_max > 40 or d <= st.r_max:
            continue
        half = np.arcsin(min(1.0, st.r_max / d)) + 1e-3 + footprint_rad
        da = np.angle(np.exp(1j * (az - np.arctan2(c[1], c[0]))))
        cols = np.nonzero(np.abs(da) <= half)[0]
        if len(cols) == 0:
            continue
        rows = (np.arange(len(el))[:, None] * n_az + cols[None, :]).ravel()
        t, k, edges = _ray_polygon(-c, u[rows], st.polygon)
        for side in (-footprint_rad, footprint_rad) if footprint_rad > 0 else ():
            rot = np.array([[np.cos(side), -np.sin(side)], [np.sin(side), np.cos(side)]])
            t2, k2, _ = _ray_polygon(-c, u[rows] @ rot.T, st.polygon)
            nearer = t2 < t
            t, k = np.where(nearer, t2, t), np.where(nearer, k2, k)
        z = t * np.tan(e[rows])
        hit = np.isfinite(t) & (t < t_xy[rows]) & (z > -sensor_height_m) & (z < 15.0)
        rows, t, k = rows[hit], t[hit], k[hit]
        t_xy[rows] = t
        kind[rows] = 2
        obj[rows] = factor
        nrm = np.c_[edges[k, 1], -edges[k, 0]] / np.linalg.norm(edges[k], axis=1)[:, None]
        cos_inc[rows] = np.abs(np.sum(nrm * u[rows], axis=1)) * np.cos(e[rows])
    rng_m = t_xy / np.cos(e)
    keep = np.isfinite(rng_m) & (rng_m >= profile.range_min_m) & (rng_m <= 60.0)
    keep &= rng.random(len(a)) >= profile.dropout_rate
    r = rng_m[keep] + rng.normal(0, noise, keep.sum())
    d3 = np.c_[np.cos(e[keep]) * u[keep, 0], np.cos(e[keep]) * u[keep, 1], np.sin(e[keep])]
    points = d3 * r[:, None]
    kk, ci = kind[keep], cos_inc[keep]
    if style.intensity == "flat":
        intensity = np.where(kk == 2, 40.0, 20.0)
    elif style.intensity == "material":
        median = np.where(kk == 2, 70.0 * obj[keep], 40.0)
        falloff = np.minimum(1.0, np.sqrt(8.0 / np.maximum(r, 1e-3)))
        intensity = median * ci * falloff * rng.lognormal(0, 0.3, len(r))
    else:
        refl = np.where(kk == 2, 95.0, 60.0)
        falloff = 1.0 / (1.0 + (r / 40.0) ** 2)
        intensity = gain * refl * ci**0.7 * falloff * rng.lognormal(0, 0.15, len(r))
    return Scan(
        0.0, points, intensity=intensity.astype(np.float32), ring=ring[keep].astype(np.uint16)
    )
