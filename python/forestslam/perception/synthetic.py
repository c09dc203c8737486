"""Analytic test scenes for perception: a sensor above a (possibly sloped) ground plane among
vertical cylinders (stems), ray cast exactly for a profile's beam pattern. Used by the tests
and the benchmark; the full forest simulator is `forestslam.sim`."""

from __future__ import annotations

import numpy as np

from forestslam.io.scan import Scan
from forestslam.sensors import SensorProfile, load_profile


def synthetic_scan(
    sensor: str | SensorProfile,
    trees: np.ndarray,
    sensor_height_m: float = 1.8,
    slope: tuple[float, float] = (0.0, 0.0),
    tree_height_m: float = 12.0,
    noise_m: float | None = None,
    bushes: np.ndarray | None = None,
    seed: int = 0,
) -> Scan:
    """One scan of stems `trees` (T,3) = x, y, dbh (sensor frame, metres) standing on the
    ground z = -sensor_height_m + slope[0] x + slope[1] y. `bushes` (B,3) = x, y, radius adds
    bright spherical foliage blobs 0.5-1.5 m above ground. Range noise defaults to the
    profile's; ring = beam index; intensity: stems 40, ground 20, foliage 160."""
    profile = load_profile(sensor)
    rng = np.random.default_rng(seed)
    noise = profile.range_noise_m if noise_m is None else noise_m
    el = profile.vertical_angles_rad
    n_az = profile.image_cols
    fov = np.radians(profile.horizontal_fov_deg)
    az = (
        -fov / 2 + (np.arange(n_az) + 0.5) * fov / n_az
        if fov < 2 * np.pi - 1e-6
        else (-np.pi + (np.arange(n_az) + 0.5) * 2 * np.pi / n_az)
    )
    ring = np.repeat(np.arange(len(el)), n_az)
    e = el[ring]
    a = np.tile(az, len(el))
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    t = np.full(len(d), np.inf)
    kind = np.zeros(len(d), dtype=np.int8)  # 0 none, 1 ground, 2 stem, 3 bush
    sx, sy = slope
    denom = d[:, 2] - sx * d[:, 0] - sy * d[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = -sensor_height_m / denom
    ok = np.isfinite(tg) & (tg > 0)
    t[ok] = tg[ok]
    kind[ok] = 1
    trees = np.asarray(trees, dtype=np.float64).reshape(-1, 3)
    dxy = d[:, :2]
    a2 = np.sum(dxy**2, axis=1)
    for cx, cy, dbh in trees:
        r = dbh / 2
        c = np.array([cx, cy])
        b = -2 * dxy @ c
        cc = c @ c - r * r
        disc = b * b - 4 * a2 * cc
        hit = disc >= 0
        th = np.full(len(d), np.inf)
        th[hit] = (-b[hit] - np.sqrt(disc[hit])) / (2 * a2[hit])
        with np.errstate(invalid="ignore"):
            z = th * d[:, 2]
        zg = -sensor_height_m + sx * cx + sy * cy
        hit &= (th > 0) & (z >= zg) & (z <= zg + tree_height_m) & (th < t)
        t[hit] = th[hit]
        kind[hit] = 2
    if bushes is not None:
        for bx, by, br in np.asarray(bushes, dtype=np.float64).reshape(-1, 3):
            centre = np.array([bx, by, -sensor_height_m + sx * bx + sy * by + 1.0])
            b = d @ centre
            disc = b * b - (centre @ centre - br * br)
            hit = disc >= 0
            th = np.full(len(d), np.inf)
            th[hit] = b[hit] - np.sqrt(disc[hit])
            # Foliage is porous: only part of the rays stop in it, at a random depth.
            hit &= (th > 0) & (th < t) & (rng.random(len(d)) < 0.6)
            t[hit] = th[hit] + rng.random(hit.sum()) * br
            kind[hit] = 3
    keep = np.isfinite(t) & (t >= profile.range_min_m) & (t <= profile.range_max_m)
    keep &= rng.random(len(d)) >= profile.dropout_rate
    rng_m = t[keep] + rng.normal(0.0, noise, keep.sum())
    points = d[keep] * rng_m[:, None]
    intensity = np.choose(kind[keep] - 1, [20.0, 40.0, 160.0]).astype(np.float32)
    return Scan(0.0, points, intensity=intensity, ring=ring[keep].astype(np.uint16), time=None)


def random_stand(
    n_trees: int, radius_m: float, seed: int = 0, min_spacing_m: float = 1.5
) -> np.ndarray:
    """(T,3) x, y, dbh of trees scattered in a disc around the sensor, DBH 0.1-0.5 m, none
    closer than 1.5 m to the sensor or min_spacing_m to each other."""
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    for _ in range(50 * n_trees):
        if len(out) == n_trees:
            break
        p = rng.uniform(-radius_m, radius_m, 2)
        if not 1.5 < np.linalg.norm(p) < radius_m:
            continue
        if any(np.linalg.norm(p - q[:2]) < min_spacing_m for q in out):
            continue
        out.append(np.array([p[0], p[1], rng.uniform(0.1, 0.5)]))
    return np.array(out).reshape(-1, 3)
