"""Heightfield terrain: smooth relief from random Fourier modes plus cell-scale roughness.

Heights are piecewise linear over triangles (each cell split along its (0,0)-(1,1) diagonal),
exactly as the C++ ray caster intersects them, so `height_at` here and the rays agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.config import TerrainConfig


@dataclass
class Terrain:
    x0: float
    y0: float
    cell: float
    z: np.ndarray  # (ny+1, nx+1) vertex heights

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Heights at xy (N,2) (clamped to the grid edge outside it)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ny, nx = self.z.shape[0] - 1, self.z.shape[1] - 1
        gx = np.clip((xy[:, 0] - self.x0) / self.cell, 0.0, nx)
        gy = np.clip((xy[:, 1] - self.y0) / self.cell, 0.0, ny)
        ix = np.minimum(gx.astype(np.int64), nx - 1)
        iy = np.minimum(gy.astype(np.int64), ny - 1)
        fx, fy = gx - ix, gy - iy
        z00, z10 = self.z[iy, ix], self.z[iy, ix + 1]
        z01, z11 = self.z[iy + 1, ix], self.z[iy + 1, ix + 1]
        lower = z00 + fx * (z10 - z00) + fy * (z11 - z10)
        upper = z00 + fy * (z01 - z00) + fx * (z11 - z01)
        return np.where(fx >= fy, lower, upper)


def make_terrain(
    cfg: TerrainConfig, bounds: tuple[float, float, float, float], rng: np.random.Generator
) -> Terrain:
    """Terrain over `bounds` (xmin, ymin, xmax, ymax) grown by the margin."""
    if cfg.cell_m <= 0 or cfg.relief_m < 0 or cfg.roughness_m < 0:
        raise InputError("terrain: cell_m must be > 0, relief_m and roughness_m >= 0")
    if cfg.relief_wavelength_m <= 0:
        raise InputError("terrain: relief_wavelength_m must be > 0")
    x0 = np.floor((bounds[0] - cfg.margin_m) / cfg.cell_m) * cfg.cell_m
    y0 = np.floor((bounds[1] - cfg.margin_m) / cfg.cell_m) * cfg.cell_m
    nx = int(np.ceil((bounds[2] + cfg.margin_m - x0) / cfg.cell_m))
    ny = int(np.ceil((bounds[3] + cfg.margin_m - y0) / cfg.cell_m))
    if nx * ny > 2.5e7:
        raise InputError(f"terrain grid of {nx} x {ny} cells is too large; raise terrain.cell_m")
    xs = x0 + cfg.cell_m * np.arange(nx + 1)
    ys = y0 + cfg.cell_m * np.arange(ny + 1)
    # Relief: modes with wavelengths between 0.5x and 2x the nominal one, random directions.
    n_modes = 12
    wavelength = cfg.relief_wavelength_m * np.exp(rng.uniform(np.log(0.5), np.log(2.0), n_modes))
    direction = rng.uniform(0, 2 * np.pi, n_modes)
    phase = rng.uniform(0, 2 * np.pi, n_modes)
    amplitude = wavelength / wavelength.max()  # red spectrum: long waves dominate
    kx = 2 * np.pi * np.cos(direction) / wavelength
    ky = 2 * np.pi * np.sin(direction) / wavelength
    relief = np.zeros((ny + 1, nx + 1))
    for a, u, v, p in zip(amplitude, kx, ky, phase, strict=True):  # 12 modes, vectorised grids
        relief += a * np.cos(u * xs[None, :] + v * ys[:, None] + p)
    # Scale so the relief spans +-relief_m over the area of interest (not the margin).
    inner = (
        (xs[None, :] >= bounds[0])
        & (xs[None, :] <= bounds[2])
        & (ys[:, None] >= bounds[1])
        & (ys[:, None] <= bounds[3])
    )
    inner_vals = relief[inner] if inner.any() else relief.ravel()
    relief -= 0.5 * (inner_vals.max() + inner_vals.min())
    span = 0.5 * (inner_vals.max() - inner_vals.min())
    relief *= cfg.relief_m / span if span > 0 else 0.0
    rough = rng.normal(0.0, cfg.roughness_m, relief.shape) if cfg.roughness_m > 0 else 0.0
    return Terrain(float(x0), float(y0), float(cfg.cell_m), np.ascontiguousarray(relief + rough))
