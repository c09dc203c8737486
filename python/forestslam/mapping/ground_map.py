"""Ground map (map3d mode): voxelized ground points and a DTM grid.

Ground points are kept per keyframe in that keyframe's sensor frame (downsampled), so the global
map is rebuilt from the *optimised* keyframe poses whenever it is written: loop closures move
the ground with the trajectory instead of smearing it. Memory is bounded by the voxel size:
about (keyframe area / voxel^2) points per keyframe.

DTM: a regular XY grid of `cell_m` cells over the ground map; each cell holds the mean height of
the ground voxels in it (NaN where fewer than `min_points`). Saved as `dtm.npz` (arrays `z`
(ny,nx), `x0`, `y0` the centre of cell [0,0], `cell_m`; row i is y0 + i*cell_m, column j is
x0 + j*cell_m), as `dtm.csv` (x,y,z per defined cell) and as a shaded `dtm.png`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from forestslam.geometry import transform_points
from forestslam.mapping.voxel import voxel_downsample


class GroundMap:
    def __init__(self, keyframe_voxel_m: float = 0.2, voxel_m: float = 0.2) -> None:
        self.keyframe_voxel_m = keyframe_voxel_m
        self.voxel_m = voxel_m
        self._kf: list[int] = []
        self._points: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._kf)

    @property
    def n_points(self) -> int:
        return int(sum(len(p) for p in self._points))

    def add_keyframe(self, keyframe: int, points_sensor: np.ndarray) -> None:
        """Ground points (G,3) of a keyframe in its sensor frame."""
        pts = voxel_downsample(points_sensor, self.keyframe_voxel_m).astype(np.float32)
        self._kf.append(int(keyframe))
        self._points.append(pts)

    def build(self, keyframe_poses: np.ndarray) -> np.ndarray:
        """The voxelized ground map (M,3) from the keyframe poses (K,4,4) (indexed by keyframe)."""
        parts = []
        for kf, pts in zip(self._kf, self._points, strict=True):
            if len(pts) and kf < len(keyframe_poses):
                t = keyframe_poses[kf]
                parts.append(transform_points(t, pts))
        if not parts:
            return np.zeros((0, 3))
        return voxel_downsample(np.concatenate(parts), self.voxel_m)


def dtm_grid(
    points: np.ndarray,
    cell_m: float = 0.5,
    min_points: int = 2,
    window_m: float = 5.0,
    max_raise_m: float = 0.3,
) -> dict:
    """Mean-height grid of points (N,3): dict(z (ny,nx) with NaN holes, x0, y0, cell_m); cells
    raised above their surroundings are then removed (`remove_raised_cells`, off with
    window_m <= 0)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return {"z": np.full((0, 0), np.nan), "x0": 0.0, "y0": 0.0, "cell_m": cell_m}
    lo = np.floor(points[:, :2].min(axis=0) / cell_m) * cell_m
    ij = np.floor((points[:, :2] - lo) / cell_m).astype(np.int64)
    nx, ny = ij[:, 0].max() + 1, ij[:, 1].max() + 1
    flat = ij[:, 1] * nx + ij[:, 0]
    counts = np.bincount(flat, minlength=nx * ny)
    sums = np.bincount(flat, weights=points[:, 2], minlength=nx * ny)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(counts >= min_points, sums / counts, np.nan).reshape(ny, nx)
    z = remove_raised_cells(z, cell_m, window_m, max_raise_m)
    return {
        "z": z,
        "x0": float(lo[0] + cell_m / 2),
        "y0": float(lo[1] + cell_m / 2),
        "cell_m": cell_m,
    }


def remove_raised_cells(
    z: np.ndarray, cell_m: float, window_m: float = 5.0, max_raise_m: float = 0.3
) -> np.ndarray:
    """z (ny,nx) with NaN for cells more than max_raise_m above the local ground plane: shrubs,
    logs and stem feet that the per-scan ground filter let through.

    The plane of every cell is a Gaussian-weighted least-squares fit (sigma window_m / 2) to the
    known cells around it, fitted twice: the second fit leaves out the cells the first found
    raised, so an object does not lift its own reference. Slopes and map edges or holes are
    handled alike (a fitted plane extrapolates; a morphological opening would cut an uphill edge);
    a smooth hill's curvature shifts the plane by about f'' sigma^2 / 2 (centimetres)."""
    z = np.asarray(z, dtype=np.float64)
    if window_m <= 0 or z.size == 0 or not np.isfinite(z).any():
        return z
    known = np.isfinite(z)
    use = known.copy()
    for _ in range(2):
        plane = _local_plane(np.where(use, z, 0.0), use, window_m / 2.0 / cell_m)
        use = known & ~(z - plane > max_raise_m)
    out = z.copy()
    out[known & (z - plane > max_raise_m)] = np.nan
    return out


def _local_plane(z: np.ndarray, w: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Height at every cell of the plane fitted to z where w (weights 0/1), Gaussian window of
    sigma_cells; NaN where the window holds too little to fit a plane."""
    from scipy.ndimage import correlate1d

    r = int(np.ceil(3 * sigma_cells))
    u = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (u / sigma_cells) ** 2)
    kernels = {0: g, 1: u * g, 2: u * u * g}

    def moment(f, px, py):  # sum over the window of w f (dx)^px (dy)^py, per cell
        return correlate1d(
            correlate1d(f, kernels[px], axis=1, mode="constant"),
            kernels[py],
            axis=0,
            mode="constant",
        )

    wf, wz = w.astype(np.float64), z * w
    s1, sx, sy = moment(wf, 0, 0), moment(wf, 1, 0), moment(wf, 0, 1)
    sxx, sxy, syy = moment(wf, 2, 0), moment(wf, 1, 1), moment(wf, 0, 2)
    sz, sxz, syz = moment(wz, 0, 0), moment(wz, 1, 0), moment(wz, 0, 1)
    a = np.stack(
        [np.stack([s1, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)],
        -2,
    )
    b = np.stack([sz, sxz, syz], -1)
    ok = np.linalg.det(a) > 1e-6 * np.maximum(s1, 1e-12) ** 3
    plane = np.full(z.shape, np.nan)
    plane[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0, 0]
    return plane


def write_dtm(out_dir: Path, dtm: dict) -> None:
    """dtm.npz and dtm.csv, atomically."""
    from forestslam.io.atomic import atomic_write, atomic_write_text

    out_dir = Path(out_dir)
    atomic_write(
        out_dir / "dtm.npz",
        lambda f: np.savez_compressed(
            f, z=dtm["z"], x0=dtm["x0"], y0=dtm["y0"], cell_m=dtm["cell_m"]
        ),
        mode="wb",
    )
    z = dtm["z"]
    iy, ix = np.nonzero(np.isfinite(z))
    x = dtm["x0"] + ix * dtm["cell_m"]
    y = dtm["y0"] + iy * dtm["cell_m"]
    rows = np.column_stack([x, y, z[iy, ix]])
    lines = "\n".join(f"{a:.3f},{b:.3f},{c:.3f}" for a, b, c in rows.tolist())
    atomic_write_text(out_dir / "dtm.csv", "x,y,z\n" + lines + ("\n" if len(rows) else ""))
