"""Simulator geometry with exact answers: ranges to stems and ground, beam elevations, truth DBH."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

core = pytest.importorskip("forestslam._core")
if not hasattr(core, "SimScene"):
    pytest.skip("forestslam._core built without the simulator", allow_module_level=True)

from forestslam.sensors import load_profile  # noqa: E402
from forestslam.sim.forest import BREAST_HEIGHT_M, GROUND, STEM  # noqa: E402
from forestslam.sim.scanner import make_pattern, synthesize_scan  # noqa: E402

EMPTY8 = np.zeros((0, 8))


def _stem_row(x, y, r, height=15.0, taper=0.0, bark=0.0):
    return [x, y, 0.0, 0.0, 0.0, r, r, 0.0, taper, -0.3, height, bark]


def test_ray_against_vertical_cylinder_gives_known_range():
    stems = np.array([_stem_row(5.0, 0.0, 0.2), _stem_row(0.0, -7.0, 0.35)])
    scene = core.SimScene(0, 0, 1, np.zeros((0, 0)), stems, EMPTY8, EMPTY8)
    origins = np.array([[0.0, 0.0, 1.3]])
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.1 / 5.0, 0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rng_, surface, obj, _ = scene.cast(origins, dirs, 0.1, 100.0, 0)
    assert rng_[0] == pytest.approx(4.8, abs=1e-9)
    assert rng_[1] == pytest.approx(7.0 - 0.35, abs=1e-9)
    assert np.isnan(rng_[2])
    # Off-centre ray through (5, 0.1): distance to the circle along the ray, from geometry.
    d = dirs[3]
    b = -2 * d @ np.array([5.0, 0.0, 0.0])
    c = 25.0 - 0.04
    expected = (-b - np.sqrt(b * b - 4 * c)) / 2
    assert rng_[3] == pytest.approx(expected, abs=1e-9)
    assert list(surface[:2]) == [STEM, STEM] and list(obj[:2]) == [0, 1]


def _flat_scene(z=0.0, size=300.0):
    n = int(size / 0.5)
    return core.SimScene(
        -size / 2, -size / 2, 0.5, np.full((n + 1, n + 1), z), np.zeros((0, 12)), EMPTY8, EMPTY8
    )


def _static_poses(pattern, height):
    poses = np.tile(np.eye(4), (len(pattern.group_time), 1, 1))
    poses[:, 2, 3] = height
    return poses


@pytest.mark.parametrize("name", ["vlp16", "hdl32", "os1-64", "rs-m1"])
def test_static_sensor_in_empty_world_sees_only_ground_at_predicted_ranges(name):
    profile = dataclasses.replace(load_profile(name), range_noise_m=0.0, dropout_rate=0.0)
    pattern = make_pattern(profile)
    height = 1.2
    scan, surface, _ = synthesize_scan(
        _flat_scene(),
        pattern,
        _static_poses(pattern, height),
        profile,
        10.0,
        np.random.default_rng(0),
        1,
        0.1,
        labels=True,
    )
    assert len(scan) > 0 and (surface == GROUND).all()
    r = np.linalg.norm(scan.points, axis=1)
    sin_el = -scan.points[:, 2] / r
    # Every return lies on the ground plane z = -height in the sensor frame, at h / sin(-elev).
    np.testing.assert_allclose(r, height / sin_el, rtol=0, atol=1e-9)
    np.testing.assert_allclose(scan.points[:, 2], -height, atol=1e-9)
    # Exactly the downward beams whose ground range is within the profile's limits return.
    down = pattern.dirs[:, 2] < 0
    ranges = height / -pattern.dirs[down, 2]
    expected = int(((ranges >= profile.range_min_m) & (ranges <= profile.range_max_m)).sum())
    assert len(scan) == expected


@pytest.mark.parametrize("name", ["vlp16", "hdl32", "os1-64"])
def test_beam_elevations_match_profile(name):
    profile = load_profile(name)
    pattern = make_pattern(profile)
    cols = int(round(360.0 / profile.azimuth_resolution_deg))
    assert len(pattern.dirs) == cols * profile.channels
    elev = np.arcsin(pattern.dirs[:, 2])
    np.testing.assert_allclose(elev, profile.vertical_angles_rad[pattern.ring], atol=1e-12)
    # Per-point time covers one revolution, columns in firing order.
    assert pattern.time.min() == 0.0 and pattern.time.max() < 1.0 / profile.rate_hz
    assert (np.diff(pattern.time) >= 0).all()


def test_range_noise_and_dropout_follow_profile():
    profile = dataclasses.replace(load_profile("vlp16"), range_noise_m=0.02, dropout_rate=0.1)
    pattern = make_pattern(profile)
    scan = synthesize_scan(
        _flat_scene(),
        pattern,
        _static_poses(pattern, 1.0),
        profile,
        0.0,
        np.random.default_rng(3),
        1,
        0.1,
    )
    r = np.linalg.norm(scan.points, axis=1)
    true_r = 1.0 / (-scan.points[:, 2] / r)  # elevation is exact, only range is noisy
    resid = r - np.linalg.norm(scan.points / r[:, None] * true_r[:, None], axis=1)
    assert np.std(resid) == pytest.approx(0.02, rel=0.05)
    assert abs(np.mean(resid)) < 0.002
    full = 8 * 1800  # eight downward beams
    assert len(scan) / full == pytest.approx(0.9, abs=0.01)


def test_truth_dbh_equals_modelled_stem_diameter_at_breast_height():
    from forestslam.sim.config import ClutterConfig, StandConfig, StemConfig, TerrainConfig
    from forestslam.sim.forest import build_forest
    from forestslam.sim.stand import load_stand
    from forestslam.sim.terrain import make_terrain

    stand = load_stand(StandConfig(size_m=(40, 40), min_spacing_m=3.0, density_per_ha=150), seed=4)
    terrain = make_terrain(
        TerrainConfig(relief_m=1.0, roughness_m=0.03), stand.bounds, np.random.default_rng(1)
    )
    clutter = ClutterConfig(branches_per_tree=0, shrubs_per_ha=0, logs_per_ha=0)
    for bark, tol in ((0.0, 2e-4), (0.003, 2e-3)):
        forest = build_forest(stand, terrain, StemConfig(bark_amplitude_m=bark), clutter, None, 9)
        scene = core.SimScene(
            terrain.x0,
            terrain.y0,
            terrain.cell,
            terrain.z,
            forest.stems,
            forest.cylinders,
            forest.foliage,
            seed=9,
        )
        t = forest.trees
        az = np.linspace(0, 2 * np.pi, 720, endpoint=False)
        out = np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)])
        for i in range(0, len(t["id"]), max(1, len(t["id"]) // 8)):
            centre = np.array([t["x"][i], t["y"][i], t["z_ground"][i] + BREAST_HEIGHT_M])
            origins = centre + 1.0 * out
            rng_, surface, obj, _ = scene.cast(origins, -out, 0.0, 5.0, 0)
            assert (obj == i).all() and (surface == STEM).all()
            radial = 1.0 - rng_
            # Mean diameter of the section: max + min radial distance (the ellipse axes).
            diameter = radial.max() + radial.min() if bark == 0 else 2 * radial.mean()
            assert diameter == pytest.approx(t["dbh_m"][i], abs=tol)
        np.testing.assert_allclose(t["dbh_m"], stand.dbh, atol=1e-12)
