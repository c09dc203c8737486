"""Stem-centre (virtual) and DoG (real) features through the bindings."""

from __future__ import annotations

import numpy as np
import pytest

from forestslam import _core
from forestslam.perception.synthetic import synthetic_scan

TREES = np.array([[4.0, 1.0, 0.30], [-3.0, 4.0, 0.44], [-5.0, -4.0, 0.24], [6.0, -5.0, 0.36]])


def _ring_scan():
    return synthetic_scan("vlp16", TREES, sensor_height_m=1.2, seed=3)


def test_virtual_features_by_ring_find_known_centres():
    scan = _ring_scan()
    vf = _core.extract_virtual_features(scan.points, np.asarray(scan.ring, dtype=np.uint16))
    stems, radii = vf.stems, vf.stem_radii
    assert len(stems) == len(TREES)
    for x, y, dbh in TREES:
        d = np.linalg.norm(stems[:, :2] - [x, y], axis=1)
        k = int(np.argmin(d))
        assert d[k] < 0.03
        assert abs(radii[k] - dbh / 2) < 0.02
    assert vf.centres.shape == (len(vf.radii), 3)
    assert set(np.unique(vf.stem_ids)) == set(range(len(stems)))


def test_virtual_features_by_layer_on_dense_rings():
    # Full circles every 5 cm in height: layer mode recovers centre and radius to a few mm.
    rng = np.random.default_rng(0)
    parts = []
    for x, y, dbh in TREES:
        a = rng.uniform(0, 2 * np.pi, 4000)
        z = rng.uniform(0.0, 3.0, 4000)
        parts.append(np.column_stack([x + dbh / 2 * np.cos(a), y + dbh / 2 * np.sin(a), z]))
    vf = _core.extract_virtual_features(np.concatenate(parts))
    assert len(vf.stems) == len(TREES)
    for x, y, dbh in TREES:
        k = int(np.argmin(np.linalg.norm(vf.stems[:, :2] - [x, y], axis=1)))
        assert np.linalg.norm(vf.stems[k, :2] - [x, y]) < 0.005
        assert abs(vf.stem_radii[k] - dbh / 2) < 0.005


def test_dog_keypoints_bounded_and_rigid_invariant_response():
    scan = _ring_scan()
    config = _core.DogKeypointsConfig()
    config.max_keypoints = 150
    found = _core.detect_dog_keypoints(scan.points, config)
    kp, resp = found.points, found.response
    assert 50 <= len(kp) <= 150
    assert np.all(resp > 0)
    # Keypoints are points of the cloud (after voxel averaging: within a voxel of one).
    d = np.min(np.linalg.norm(scan.points[None, :, :] - kp[:20, None, :], axis=2), axis=1)
    assert np.all(d < 0.1)


def test_bad_inputs():
    empty = np.zeros((0, 3))
    assert len(_core.extract_virtual_features(empty).centres) == 0
    assert len(_core.detect_dog_keypoints(empty).points) == 0
    with pytest.raises(TypeError):  # options are a typed DogKeypointsConfig, no keywords
        _core.detect_dog_keypoints(empty, sigma=1.0)
    with pytest.raises(AttributeError):
        _core.DogKeypointsConfig().sigma = 1.0
    with pytest.raises(ValueError, match="rings"):
        _core.extract_virtual_features(np.zeros((3, 3)), np.zeros(2, dtype=np.uint16))
