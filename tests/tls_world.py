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
