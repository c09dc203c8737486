"""DTM cleaning: cells raised above their surroundings (shrubs, logs) go, slopes and ridges stay."""

import numpy as np

from forestslam.mapping import dtm_grid, remove_raised_cells


def hill(cell=0.5, n=120):
    """A 60 m grid: 15 % slope plus a 1.5 m hill of 40 m wavelength (convex and concave parts)."""
    x, y = np.meshgrid(np.arange(n) * cell, np.arange(n) * cell)
    return x, y, 0.15 * x + 0.75 * np.sin(2 * np.pi * x / 40.0) * np.cos(2 * np.pi * y / 40.0)


def test_terrain_alone_keeps_every_cell():
    _, _, z = hill()
    out = remove_raised_cells(z, 0.5)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out, z)


def test_shrubs_and_a_log_are_removed_holes_ignored():
    x, y, z = hill()
    ground = z.copy()
    z[50:54, 30:34] += 1.2
    z[80, 20:40] += 0.4
    z[10:13, 100:103] += 0.15
    z[60:70, 60:70] = np.nan  # a hole in the map
    out = remove_raised_cells(z, 0.5, window_m=5.0, max_raise_m=0.3)
    assert np.isnan(out[50:54, 30:34]).all()
    assert np.isnan(out[80, 20:40]).all()
    np.testing.assert_array_equal(out[10:13, 100:103], z[10:13, 100:103])
    kept = np.isfinite(out)
    assert kept.sum() == np.isfinite(z).sum() - 16 - 20
    np.testing.assert_array_equal(out[kept], z[kept])
    assert np.abs(out[kept] - ground[kept]).max() <= 0.15 + 1e-12


def test_dtm_grid_cleans_and_can_be_told_not_to():
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 30, (60_000, 2))
    z = 0.1 * xy[:, 0]
    on_shrub = np.hypot(xy[:, 0] - 15, xy[:, 1] - 15) < 1.0
    z[on_shrub] += 1.0
    pts = np.c_[xy, z]
    cleaned, raw = dtm_grid(pts, 0.5), dtm_grid(pts, 0.5, window_m=0.0)
    assert np.isfinite(raw["z"]).sum() - np.isfinite(cleaned["z"]).sum() >= 9
    gx = cleaned["x0"] + np.arange(cleaned["z"].shape[1]) * 0.5
    gy = cleaned["y0"] + np.arange(cleaned["z"].shape[0]) * 0.5
    err = np.abs(cleaned["z"] - 0.1 * gx[None, :])
    # Cells the shrub only partly covers keep a cell mean below the 0.3 m threshold.
    away = np.hypot(gx[None, :] - 15, gy[:, None] - 15) > 1.5
    assert np.nanmax(err[away]) < 0.02
    assert np.nanmax(err) <= 0.3
    assert np.nanmax(np.abs(raw["z"] - 0.1 * gx[None, :])) > 0.9
    assert remove_raised_cells(np.full((4, 4), np.nan), 0.5).shape == (4, 4)
