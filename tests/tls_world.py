"""Synthetic plot for the MLS-to-TLS tests: flat ground, vertical stems, a dense TLS reference
(station at the origin of the TLS frame, 1.5 m above ground) and VLP-16 frames ray cast by
forestslam.perception.synthetic."""

from __future__ import annotations

import numpy as np

from forestslam.io import Scan
from forestslam.perception.synthetic import synthetic_scan

STATION_HEIGHT_M = 1.5
MLS_HEIGHT_M = 1.2


def stand(seed: int = 1, n: int = 14, half: float = 9.0) -> np.ndarray:
    """Stems (n,3) = x, y, dbh in the TLS frame, kept apart and away from the station."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        p = rng.uniform(-half, half, 2)
        if np.linalg.norm(p) < 2.0 or any(np.linalg.norm(p - q[:2]) < 2.2 for q in out):
            continue
        out.append([p[0], p[1], rng.uniform(0.15, 0.45)])
    return np.array(out)


def reference_cloud(trees: np.ndarray, half: float = 11.0, spacing: float = 0.05) -> np.ndarray:
    """TLS-like reference: ground grid plus the station-facing half of each stem (a single
    station sees about half of every stem), 0.4-4 m above ground, 2 mm noise."""
    rng = np.random.default_rng(5)
    g = np.arange(-half, half, spacing)
    gx, gy = np.meshgrid(g, g)
    ground = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -STATION_HEIGHT_M)], axis=1)
    parts = [ground]
    for x, y, dbh in trees:
        r = dbh / 2
        facing = np.arctan2(-y, -x)
        ang = facing + np.linspace(-np.pi / 2, np.pi / 2, int(np.pi * r / 0.01))
        zs = np.arange(-STATION_HEIGHT_M, 4.0 - STATION_HEIGHT_M, 0.02)
        a, z = np.meshgrid(ang, zs)
        parts.append(np.stack([x + r * np.cos(a.ravel()), y + r * np.sin(a.ravel()), z.ravel()], 1))
    pts = np.concatenate(parts)
    return pts + rng.normal(0.0, 0.002, pts.shape)


def pose(x: float, y: float, yaw: float, z: float = MLS_HEIGHT_M - STATION_HEIGHT_M) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = [x, y, z]
    return T


def mls_frame(
    trees: np.ndarray,
    T_tls_sensor: np.ndarray,
    stamp: float,
    seed: int = 0,
    with_times: bool = False,
) -> Scan:
    """VLP-16 scan from a levelled pose (x, y, yaw) at MLS_HEIGHT_M above the ground. With
    with_times, per-point times of a 0.1 s sweep (from the azimuth), the pose held still."""
    R = T_tls_sensor[:2, :2]
    local = (trees[:, :2] - T_tls_sensor[:2, 3]) @ R
    frame_trees = np.column_stack([local, trees[:, 2]])
    scan = synthetic_scan("vlp16", frame_trees, sensor_height_m=MLS_HEIGHT_M, seed=seed)
    times = scan.time
    if with_times:
        az = np.arctan2(scan.points[:, 1], scan.points[:, 0])
        times = 0.1 * (az + np.pi) / (2 * np.pi)
    return Scan(stamp, scan.points, scan.intensity, scan.ring, times)


def oval_stand(seed: int = 2, n: int = 14, half: float = 9.0, ovality: float = 0.1) -> np.ndarray:
    """Polygonal, oval stems (n,6) = x, y, semi-axes a, b, angle of a, sides (TLS frame):
    stand()'s positions and mean diameters, the axes differing by `ovality` ((a - b) / a),
    sections with 9-16 corners on that ellipse (as bench/tls_bench.py --style b's stems)."""
    rng = np.random.default_rng(seed + 100)
    base = stand(seed, n, half)
    r = base[:, 2] / 2
    a, b = r * 2 / (2 - ovality), r * 2 * (1 - ovality) / (2 - ovality)
    sides = rng.integers(9, 17, n)
    return np.column_stack([base[:, :2], a, b, rng.uniform(0, np.pi, n), sides])


def _corners(stem: np.ndarray) -> np.ndarray:
    """The section corners (k+1,2) of one stem (closed: the first repeated)."""
    cx, cy, sa, sb, ang, sides = stem
    t = np.linspace(0, 2 * np.pi, int(sides) + 1)
    c, s = np.cos(ang), np.sin(ang)
    return np.column_stack(
        [cx + c * sa * np.cos(t) - s * sb * np.sin(t), cy + s * sa * np.cos(t) + c * sb * np.sin(t)]
    )


def _oval_frame(ovals: np.ndarray, T_tls_sensor: np.ndarray) -> np.ndarray:
    """The stems (n,6) in a levelled sensor frame."""
    R = T_tls_sensor[:2, :2]
    local = (ovals[:, :2] - T_tls_sensor[:2, 3]) @ R
    yaw = np.arctan2(R[1, 0], R[0, 0])
    return np.column_stack([local, ovals[:, 2:4], ovals[:, 4] - yaw, ovals[:, 5]])


def oval_scan(ovals: np.ndarray, height_m: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """VLP-16 beams from a levelled sensor height_m above flat ground, cast onto the ground and
    the vertical polygonal stems (n,6) in its frame, with the profile's range noise ->
    (points (N,3), ring (N,))."""
    from forestslam.sensors.profile import load_profile

    profile = load_profile("vlp16")
    rng = np.random.default_rng(seed)
    el, n_az = profile.vertical_angles_rad, profile.image_cols
    az = -np.pi + (np.arange(n_az) + 0.5) * 2 * np.pi / n_az
    ring = np.repeat(np.arange(len(el)), n_az)
    e, a = el[ring], np.tile(az, len(el))
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    with np.errstate(divide="ignore"):
        t = np.where(d[:, 2] < 0, -height_m / d[:, 2], np.inf)
    for stem in ovals:
        corners = _corners(stem)
        for p, q in zip(corners[:-1], corners[1:], strict=True):
            # beam t * d meets the edge p + u (q - p), 0 <= u <= 1 (2D cross products)
            e1 = q - p
            den = d[:, 0] * e1[1] - d[:, 1] * e1[0]
            with np.errstate(divide="ignore", invalid="ignore"):
                th = (p[0] * e1[1] - p[1] * e1[0]) / den
                u = (p[0] * d[:, 1] - p[1] * d[:, 0]) / den
            z = np.where(np.isfinite(th), th * d[:, 2], 0.0)
            hit = (th > 0) & (u >= 0) & (u <= 1) & (z >= -height_m) & (z <= 12.0 - height_m)
            hit &= th < t
            t[hit] = th[hit]
    keep = np.isfinite(t) & (t >= profile.range_min_m) & (t <= profile.range_max_m)
    rng_m = t[keep] + rng.normal(0.0, profile.range_noise_m, keep.sum())
    return d[keep] * rng_m[:, None], ring[keep].astype(np.uint16)


def oval_mls_frame(ovals: np.ndarray, T_tls_sensor: np.ndarray, stamp: float, seed: int) -> Scan:
    """mls_frame of polygonal, oval stems."""
    points, ring = oval_scan(_oval_frame(ovals, T_tls_sensor), MLS_HEIGHT_M, seed)
    return Scan(stamp, points, np.full(len(points), 40.0, np.float32), ring, None)


def oval_reference_cloud(ovals: np.ndarray, half: float = 11.0) -> np.ndarray:
    """reference_cloud of polygonal, oval stems: the ground grid and the faces of each
    section that face the station (the origin), 1 cm apart, 2 mm noise."""
    rng = np.random.default_rng(5)
    g = np.arange(-half, half, 0.05)
    gx, gy = np.meshgrid(g, g)
    parts = [np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -STATION_HEIGHT_M)], axis=1)]
    zs = np.arange(-STATION_HEIGHT_M, 4.0 - STATION_HEIGHT_M, 0.02)
    for stem in ovals:
        corners = _corners(stem)
        for p, q in zip(corners[:-1], corners[1:], strict=True):
            normal = np.array([q[1] - p[1], p[0] - q[0]])  # outward: corners run anticlockwise
            if normal @ -(p + q) / 2 <= 0:
                continue
            u = np.linspace(0, 1, max(2, int(np.linalg.norm(q - p) / 0.01)))
            xy = p + u[:, None] * (q - p)
            xx, zz = np.meshgrid(xy[:, 0], zs)
            yy, _ = np.meshgrid(xy[:, 1], zs)
            parts.append(np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1))
    pts = np.concatenate(parts)
    return pts + rng.normal(0.0, 0.002, pts.shape)
