"""Perception pre-processing: intensity filter, ground segmentation, adaptive normal filter."""

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.perception import (
    PerceptionConfig,
    filter_normals,
    ground_surface,
    intensity_filter,
    segment_ground,
)
from forestslam.perception.synthetic import synthetic_scan

TREES = np.array([[4.0, 1.0, 0.3], [-7.0, 3.0, 0.4], [2.0, -9.0, 0.25], [0.0, 16.0, 0.4]])


@pytest.fixture(scope="module")
def scan():
    return synthetic_scan("vlp16", TREES, slope=(0.05, 0.0), bushes=np.array([[6, 6, 1.0]]))


def test_intensity_filter_drops_foliage_and_is_skipped_without_intensity(scan):
    kept = intensity_filter(scan, "vlp16")
    assert (kept.intensity <= 100).all()
    assert len(scan) - len(kept) == int((scan.intensity > 100).sum()) > 0
    # Profile without intensity (map) or scan without intensity: unchanged.
    assert len(intensity_filter(scan, "map")) == len(scan)
    no_int = scan.select(np.arange(len(scan)))
    no_int.intensity = None
    assert len(intensity_filter(no_int, "vlp16")) == len(scan)


def test_ground_on_a_slope(scan):
    ground = segment_ground(scan.points)
    p = scan.points
    true_ground = np.abs(p[:, 2] - (-1.8 + 0.05 * p[:, 0])) < 0.05
    near = np.hypot(p[:, 0], p[:, 1]) < 30
    recall = (ground & true_ground & near).sum() / (true_ground & near).sum()
    assert recall > 0.95
    h = p[:, 2] - (-1.8 + 0.05 * p[:, 0])
    # The lowest ring on a far stem's foot can pass as ground within the filter's slope
    # allowance (a few points, < 0.5 m up); nothing higher may.
    assert (ground & (h > 0.3)).sum() < 0.02 * (h > 0.3).sum()
    assert (ground & (h > 0.5)).sum() == 0


def test_adaptive_filter_keeps_far_stems_that_fixed_radius_loses(scan):
    ground = segment_ground(scan.points)
    candidates = np.flatnonzero(~ground).astype(np.int32)
    kept, normals = filter_normals(scan.points, "vlp16", candidates=candidates)
    assert len(kept) == len(normals)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert (np.abs(normals[:, 2]) <= np.sin(0.5236) + 1e-6).all()

    def on_tree(rows, tree):
        p = scan.points[rows]
        return int((np.hypot(p[:, 0] - tree[0], p[:, 1] - tree[1]) < tree[2]).sum())

    far = TREES[3]
    cfg = PerceptionConfig()
    cfg.filter.adaptive = False
    cfg.filter.fixed_radius_m = 0.2
    kept_fixed, _ = filter_normals(scan.points, "vlp16", cfg, candidates=candidates)
    assert on_tree(kept, far) > 10
    assert on_tree(kept_fixed, far) < on_tree(kept, far) / 4
    for tree in TREES[:3]:
        assert on_tree(kept, tree) > 10


def test_ground_surface_follows_the_slope(scan):
    surface = ground_surface(scan.points)
    centres = surface.cell_centres()
    near = np.hypot(centres[:, 0], centres[:, 1]) < 20
    assert near.sum() > 200
    err = centres[near, 2] - (-1.8 + 0.05 * centres[near, 0])
    # The lowest return of a 0.5 m cell on a 5 % slope: within 2 cm + range noise of the plane.
    assert np.median(np.abs(err)) < 0.03
    np.testing.assert_allclose(surface.height_at(centres[:, :2]), centres[:, 2])


def test_ground_surface_of_a_map_cloud_far_from_the_origin(scan):
    # A map cloud in UTM-like coordinates: same surface, shifted, no sensor range limit.
    offset = np.array([470_000.0, 3_810_000.0, 2_000.0])
    local = ground_surface(scan.points, single_scan=False)
    utm = ground_surface(scan.points + offset, single_scan=False)
    xy = local.cell_centres()[:, :2]
    np.testing.assert_allclose(
        utm.height_at(xy + offset[:2]) - offset[2], local.height_at(xy), atol=1e-6
    )
    with pytest.raises(InputError):
        ground_surface(np.full((5, 3), np.nan))
