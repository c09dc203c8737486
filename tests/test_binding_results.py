"""Results cross the binding typed, read-only and documented (issue 18), like RegistrationResult:
the perception detection and its per-stem diameters, the TLS stem-centre LM and NDT. The values
themselves are checked by each concept's own tests."""

from __future__ import annotations

import numpy as np
import pytest

_core = pytest.importorskip("forestslam._core")


def _read_only(obj, name: str) -> None:
    with pytest.raises(AttributeError):
        setattr(obj, name, getattr(obj, name))


def test_detection_is_a_typed_read_only_result_in_the_layout_of_stems():
    from forestslam.perception import PerceptionConfig
    from forestslam.perception.pipeline import core_options, sensor_geometry
    from forestslam.perception.synthetic_stems import ROUND, make_world, scan_stems
    from forestslam.sensors import load_profile

    profile = load_profile("vlp16")
    world = make_world(ROUND, seed=3, n=25, length_m=20.0)
    scan = scan_stems(world, np.array([10.0, 0.0]), ROUND, noise_m=0.01, seed=1, gain=1.3)
    det = _core.perception_detect(
        scan.points,
        None,
        None,
        sensor_geometry(profile),
        True,
        core_options(PerceptionConfig(), profile),
    )
    assert isinstance(det, _core.Detection)
    k = len(det)
    assert k >= 5
    assert np.asarray(det.xy).shape == (k, 2) and np.asarray(det.cov).shape == (k, 9)
    assert len(det.points) == k and np.asarray(det.ground).shape[1] == 3
    assert set(det.counts) >= {"input", "ground", "refined_clusters"}
    d = det.diameters[0]
    assert isinstance(d, _core.StemDiameter) and isinstance(d.circle, _core.DiameterFit)
    assert d.method in ("circle", "cylinder", "silhouette", "none")
    np.testing.assert_array_equal(det.dbh, [x.dbh for x in det.diameters])
    for name in ("xy", "dbh", "diameters", "ground"):
        _read_only(det, name)
    _read_only(d, "dbh")
    _read_only(d.circle, "radius")


def test_tls_registration_results_are_typed_and_read_only():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-5, 5, (3000, 2))
    ground = np.column_stack([xy, 0.02 * xy[:, 0] + rng.normal(0, 0.005, len(xy))])
    wall = np.column_stack([np.full(1000, 3.0), rng.uniform(-5, 5, (1000, 2))])
    cloud = np.ascontiguousarray(np.vstack([ground, wall]))
    target = _core.StemCentreTarget(cloud)
    lm = _core.register_stem_centre_lm(
        target, np.zeros((0, 3)), np.zeros(0), cloud[::10], np.eye(4), _core.StemCentreLmConfig()
    )
    assert isinstance(lm, _core.StemCentreLmResult)
    assert isinstance(lm, _core.RegistrationResult)
    assert np.asarray(lm.T_target_source).shape == (4, 4)
    assert np.asarray(lm.covariance).shape == (6, 6)
    assert lm.virtual_inliers == 0 and lm.real_inliers > 0
    assert np.asarray(lm.sweep).shape[1:] in ((6,), (0,))
    _read_only(lm, "T_target_source")
    _read_only(lm, "virtual_rms_m")
    ndt = _core.register_ndt(cloud, cloud[::5], np.eye(4), _core.NdtConfig())
    assert isinstance(ndt, _core.NdtResult)
    assert np.asarray(ndt.T_target_source).shape == (4, 4) and ndt.fitness >= 0
    _read_only(ndt, "converged")


def test_stage_results_are_typed_and_read_only():
    """The perception stages (ground, normals, cluster shape) and the TLS virtual features."""
    from forestslam.perception import PerceptionConfig
    from forestslam.perception.pipeline import _stage_options

    rng = np.random.default_rng(1)
    ground = np.column_stack([rng.uniform(-8, 8, (4000, 2)), rng.normal(0, 0.02, 4000)])
    a = rng.uniform(0, 2 * np.pi, 1500)
    stem = np.column_stack([3 + 0.2 * np.cos(a), 0.2 * np.sin(a), rng.uniform(0.2, 4, 1500)])
    cloud = np.ascontiguousarray(np.vstack([ground, stem]))
    cfg = PerceptionConfig()
    seg = _core.perception_segment_ground(
        cloud, _stage_options(cfg.ground, "ground", "GroundConfig")
    )
    assert isinstance(seg, _core.GroundSegmentation) and isinstance(seg.grid, _core.GroundGrid)
    assert seg.is_ground.dtype == bool and seg.is_ground.shape == (len(cloud),)
    assert seg.ground_count == int(seg.is_ground.sum()) and seg.grid.cell > 0
    _read_only(seg, "grid")
    nf = _core.perception_normal_filter(
        cloud,
        np.flatnonzero(~seg.is_ground).astype(np.int32),
        0.035,
        _stage_options(cfg.filter, "filter", "NormalFilterConfig"),
    )
    assert isinstance(nf, _core.NormalFilterResult)
    assert np.asarray(nf.normals).shape == (len(nf.kept), 3)
    _read_only(nf, "kept")
    shape = _core.perception_cluster_shape(stem, np.array([0.0, 0.0, 1.0]))
    assert isinstance(shape, _core.ClusterShape) and shape.axis_angle < 0.05
    assert np.asarray(shape.cov).shape == (3, 3) and 3.5 < shape.length < 4.0
    seg_cfg = _stage_options(cfg.segmentation, "segmentation", "SegmentationConfig")
    assert _core.perception_is_stem(shape, len(stem), seg_cfg)
    _read_only(shape, "axis")
    vf = _core.extract_virtual_features(cloud)
    assert isinstance(vf, _core.VirtualFeatures)
    assert np.asarray(vf.centres).shape == (len(vf.radii), 3) and len(vf.stems) == 1
    assert abs(vf.stem_radii[0] - 0.2) < 0.01
    _read_only(vf, "stems")


def test_localization_and_keypoint_results_are_typed_and_read_only():
    rng = np.random.default_rng(2)
    xy = np.ascontiguousarray(rng.uniform(0, 30, (40, 2)))
    tri = _core.delaunay(xy)
    assert isinstance(tri, _core.Triangulation) and len(tri.used_points) == 40
    assert np.asarray(tri.triangles).shape == np.asarray(tri.neighbours).shape
    stars = _core.triangle_stars(xy)
    assert isinstance(stars, _core.StarSet)
    assert np.asarray(stars.vertices).shape == (len(stars.centre), 6)
    assert np.asarray(stars.features).shape == (len(stars.centre), 8)
    _read_only(tri, "triangles")
    _read_only(stars, "features")
    a = rng.uniform(0, 2 * np.pi, 3000)
    trunk = np.column_stack([5 + 0.2 * np.cos(a), 0.2 * np.sin(a), rng.uniform(0.3, 3, 3000)])
    ground = np.column_stack([rng.uniform(0, 10, (3000, 2)), np.zeros(3000)])
    trunks = _core.extract_trunks(np.ascontiguousarray(np.vstack([ground, trunk])))
    assert isinstance(trunks, _core.Trunks) and len(trunks.sizes) == len(trunks.xy)
    _read_only(trunks, "xy")
    kp = _core.detect_dog_keypoints(np.ascontiguousarray(np.vstack([ground, trunk])))
    assert isinstance(kp, _core.DogKeypoints) and len(kp.points) == len(kp.response)
    _read_only(kp, "points")


def test_consensus_pairs_result_is_typed_and_read_only():
    rng = np.random.default_rng(4)
    target = np.column_stack([rng.uniform(0, 30, (12, 2)), np.zeros(12)])
    yaw, shift = 0.3, np.array([2.0, -1.0])
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    source = target.copy()
    source[:, :2] = (target[:, :2] - shift) @ R  # target = R source + shift
    pairs = np.column_stack([np.arange(12), np.arange(12)])
    pairs[-1] = [11, 0]  # one wrong match
    res = _core.consensus_pairs(source, target, pairs, np.eye(4), _core.ShapeRegistrationConfig())
    assert isinstance(res, _core.ConsensusPairs)
    np.testing.assert_allclose(np.asarray(res.T_target_source)[:2, :2], R, atol=1e-6)
    np.testing.assert_allclose(np.asarray(res.T_target_source)[:2, 3], shift, atol=1e-6)
    inliers = np.asarray(res.inliers)
    assert inliers.dtype.kind == "i"
    np.testing.assert_array_equal(np.sort(inliers), np.arange(11))
    for name in ("T_target_source", "inliers"):
        _read_only(res, name)
