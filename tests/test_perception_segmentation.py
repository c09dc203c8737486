"""Stem segmentation: range-image clusters, adaptive DBSCAN, SVD classification, the full
detect() on synthetic VLP-16 / HDL-32 / solid-state scans and a `map` cloud."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from forestslam.perception import (
    classify_cluster,
    coarse_clusters,
    detect,
    refine_cluster,
)
from forestslam.perception.synthetic import random_stand, synthetic_scan


def match(stems, trees, gate=0.3):
    d, j = cKDTree(stems.xy).query(trees[:, :2]) if len(stems) else (np.inf, None)
    return np.asarray(d) < gate, j


@pytest.mark.parametrize("sensor", ["vlp16", "hdl32"])
def test_detect_recall_precision_and_dbh(sensor):
    recalls, precisions, errors = [], [], []
    for seed in range(3):
        trees = random_stand(30, 20, seed=seed)
        scan = synthetic_scan(sensor, trees, seed=seed, bushes=np.array([[5.0, -5.0, 0.9]]))
        stems = detect(scan, sensor)
        # Truth: stems within 15 m that the scan actually hits (occluded ones cannot be found).
        near = trees[np.hypot(trees[:, 0], trees[:, 1]) <= 15]
        hits = np.array(
            [(np.hypot(*(scan.points[:, :2] - t[:2]).T) < t[2] / 2 + 0.03).sum() for t in near]
        )
        visible = near[hits >= 10]
        ok, j = match(stems, visible)
        recalls.append(ok.mean())
        close = stems.xy[np.hypot(*stems.xy.T) <= 15]
        d, _ = cKDTree(trees[:, :2]).query(close)
        precisions.append((d < 0.3).mean())
        errors += list(np.abs(stems.dbh[j[ok]] - visible[ok, 2]))
    assert np.mean(recalls) >= 0.9
    assert np.mean(precisions) >= 0.95
    assert np.nanmean(errors) <= 0.03
    assert np.isfinite(errors).mean() >= 0.9


def test_stem_outputs_are_consistent():
    trees = np.array([[5.0, 0.0, 0.3], [0.0, -8.0, 0.45]])
    stems = detect(synthetic_scan("vlp16", trees, sensor_height_m=1.5), "vlp16")
    assert len(stems) == 2
    assert stems.cov.shape == (2, 3, 3) and stems.mean.shape == (2, 3)
    np.testing.assert_allclose(stems.cov, np.transpose(stems.cov, (0, 2, 1)))
    np.testing.assert_allclose(np.linalg.norm(stems.axis, axis=1), 1.0, atol=1e-9)
    assert (stems.axis[:, 2] > 0.95).all()
    np.testing.assert_allclose(stems.base_z, -1.5, atol=0.1)
    np.testing.assert_allclose(stems.z, -1.5 + 1.3, atol=0.1)
    for p, m in zip(stems.points, stems.mean, strict=True):
        np.testing.assert_allclose(p.mean(0), m, atol=1e-9)
    assert len(stems.ground) > 100
    for stage in ("ground", "normals", "clustering", "classification", "diameter", "total"):
        assert stage in stems.timing


def test_solid_state_and_map_clouds():
    trees = np.array([[6.0, 1.0, 0.3], [9.0, -2.0, 0.4]])  # in the rs-m1's 120 deg view
    stems = detect(synthetic_scan("rs-m1", trees), "rs-m1")
    ok, _ = match(stems, trees)
    assert ok.all()
    # VLP-16 scans from several places and heights merged into one cloud: a `map`.
    parts = []
    for k, (dx, h) in enumerate([(0.0, 1.8), (3.0, 1.2), (-2.0, 2.4), (1.0, 1.5)]):
        shift = np.array([dx, 0.0, 0.0])
        scan = synthetic_scan("vlp16", trees - [dx, 0.0, 0.0], sensor_height_m=h, seed=k)
        parts.append(scan.points + shift + [0.0, 0.0, h - 1.8])
    stems = detect(np.vstack(parts), "map")
    ok, j = match(stems, trees)
    assert ok.all()
    np.testing.assert_allclose(stems.dbh[j], trees[:, 2], atol=0.04)


def test_stages_on_their_own():
    trees = np.array([[4.0, 0.0, 0.3], [9.0, 0.4, 0.4]])  # one behind the other
    scan = synthetic_scan("vlp16", trees, noise_m=0.005)
    p = scan.points[scan.points[:, 2] > -1.5]
    ring = scan.ring[scan.points[:, 2] > -1.5]
    clusters = coarse_clusters(p, "vlp16", ring=ring)
    assert len(clusters) == 2
    for rows in clusters:
        sub = refine_cluster(p[rows], "vlp16")
        assert len(sub) >= 1
        c = classify_cluster(p[rows][sub[0]])
        assert c.is_stem
        assert c.shape.axis_angle < 0.1
    log = np.c_[np.linspace(0, 3, 50), np.zeros(50), np.full(50, -1.0)]
    assert not classify_cluster(log).is_stem
