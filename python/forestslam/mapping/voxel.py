"""Voxel-grid downsampling by packed integer keys (numpy only, no per-point Python)."""

from __future__ import annotations

import numpy as np


def voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(N,3) -> (N,) int64 keys of the voxels holding the points (21 bits per axis)."""
    idx = np.floor(points / voxel_m).astype(np.int64) + (1 << 20)
    if idx.size and (idx.min() < 0 or idx.max() >= (1 << 21)):
        raise ValueError(f"points span more than {(1 << 21) * voxel_m:.0f} m at {voxel_m} m voxels")
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def voxel_downsample(
    points: np.ndarray, voxel_m: float, return_counts: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Centroid of the points in each occupied voxel: (N,3) -> (M,3) (and counts (M,))."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) == 0:
        empty = np.zeros((0, 3))
        return (empty, np.zeros(0, dtype=np.int64)) if return_counts else empty
    _, inverse, counts = np.unique(
        voxel_keys(points, voxel_m), return_inverse=True, return_counts=True
    )
    inverse = inverse.ravel()
    sums = np.zeros((len(counts), 3))
    for axis in range(3):
        sums[:, axis] = np.bincount(inverse, weights=points[:, axis], minlength=len(counts))
    centroids = sums / counts[:, None]
    return (centroids, counts) if return_counts else centroids
