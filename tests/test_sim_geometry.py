"""Simulator geometry with exact answers: ranges to stems and ground, beam elevations, truth DBH."""

from __future__ import annotations

import numpy as np
import pytest

core = pytest.importorskip("forestslam._core")
if not hasattr(core, "SimScene"):
    pytest.skip("forestslam._core built without the simulator", allow_module_level=True)

from forestslam.sensors import load_profile  # noqa: E402
from forestslam.sim.config import IntensityConfig  # noqa: E402
from forestslam.sim.forest import BREAST_HEIGHT_M, GROUND, STEM  # noqa: E402
from forestslam.sim.scanner import make_pattern, synthesize_scan  # noqa: E402
from forestslam.sim.sensor_model import SensorNoise, scan_model  # noqa: E402

EMPTY8 = np.zeros((0, 8))


def _stem_row(x, y, r, height=15.0, taper=0.0, bark=0.0):
    return [x, y, 0.0, 0.0, 0.0, r, r, 0.0, taper, -0.3, height, bark]


def test_ray_against_vertical_cylinder_gives_known_range():
    stems = np.array([_stem_row(5.0, 0.0, 0.2), _stem_row(0.0, -7.0, 0.35)])
    scene = core.SimScene(0, 0, 1, np.zeros((0, 0)), stems, EMPTY8, EMPTY8)
    origins = np.array([[0.0, 0.0, 1.3]])
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.1 / 5.0, 0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hit = scene.cast(origins, dirs, 0.1, 100.0, 0)
    rng_, surface, obj = hit.range, hit.surface, hit.object
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


def _model(profile, noise_m=0.0, dropout=0.0, divergence_mrad=0.0, grazing_cos=0.0):
    noise = SensorNoise(noise_m, divergence_mrad, dropout, grazing_cos, 1.0)
    return scan_model(profile, noise, IntensityConfig(), 0)


def _static_poses(pattern, height):
    poses = np.tile(np.eye(4), (len(pattern.group_time), 1, 1))
    poses[:, 2, 3] = height
    return poses


@pytest.mark.parametrize("name", ["vlp16", "hdl32", "os1-64", "rs-m1"])
def test_static_sensor_in_empty_world_sees_only_ground_at_predicted_ranges(name):
    profile = load_profile(name)
    pattern = make_pattern(profile)
    height = 1.2
    scan, surface, _ = synthesize_scan(
        _flat_scene(),
        pattern,
        _static_poses(pattern, height),
        _model(profile),
        10.0,
        np.random.default_rng(0),
        1,
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


def test_range_noise_and_dropout_follow_the_sensor_model():
    profile = load_profile("vlp16")
    pattern = make_pattern(profile)
    scan = synthesize_scan(
        _flat_scene(),
        pattern,
        _static_poses(pattern, 1.0),
        _model(profile, noise_m=0.02, dropout=0.1),
        0.0,
        np.random.default_rng(3),
        1,
    )
    r = np.linalg.norm(scan.points, axis=1)
    true_r = 1.0 / (-scan.points[:, 2] / r)  # elevation is exact, only range is noisy
    resid = r - np.linalg.norm(scan.points / r[:, None] * true_r[:, None], axis=1)
    assert np.std(resid) == pytest.approx(0.02, rel=0.05)
    assert abs(np.mean(resid)) < 0.002
    full = 8 * 1800  # eight downward beams
    assert len(scan) / full == pytest.approx(0.9, abs=0.01)


def test_grazing_returns_are_noisier_and_dropped():
    """The beam footprint spreads the range on inclined ground, and returns fade out below the
    grazing cosine: ground seen at low elevation (|cos| = sin(elev))."""
    profile = load_profile("vlp16")
    pattern = make_pattern(profile)
    poses = _static_poses(pattern, 1.0)
    args = (_flat_scene(), pattern, poses)
    kw = {"noise_m": 0.01, "divergence_mrad": 3.0, "grazing_cos": 0.1}
    scan = synthesize_scan(*args, _model(profile, **kw), 0.0, np.random.default_rng(3), 1)
    r = np.linalg.norm(scan.points, axis=1)
    resid = r - 1.0 / np.abs(np.sin(profile.vertical_angles_rad[scan.ring]))
    kept = np.bincount(scan.ring, minlength=16)
    # Rings 0..7 are the beams at -15..-1 deg: |cos incidence| on the ground = |sin(elev)|.
    sin_ring = np.abs(np.sin(np.radians(np.arange(-15, 0, 2))))
    expected = 1800 * np.minimum(sin_ring / 0.1, 1.0)
    np.testing.assert_allclose(kept[:8], expected, rtol=0.08)
    # Footprint: sigma^2 = 0.01^2 + (0.5 * 3e-3 * r * tan(inc))^2 (tan <= 10), larger at grazing.
    for ring in range(8):
        c = max(sin_ring[ring], 0.0995)
        expected = np.hypot(0.01, 0.5 * 3e-3 / sin_ring[ring] * np.sqrt(1 - c * c) / c)
        assert np.std(resid[scan.ring == ring]) == pytest.approx(expected, rel=0.1)


@pytest.mark.parametrize("style", ["a", "b"])
def test_truth_dbh_is_the_tape_girth_of_the_cast_section(style):
    """The ray caster's own section at 1.3 m (rays from around the stem towards its axis hit its
    boundary): its convex-hull perimeter / pi is the truth DBH, for round (a) and polygonal,
    flared, swept (b) stems; the mean radial diameter is not (bark furrows, polygon faces)."""
    from scipy.spatial import ConvexHull

    from forestslam.config_utils import from_dict
    from forestslam.sim.config import ClutterConfig, StandConfig, StemConfig, TerrainConfig
    from forestslam.sim.forest import build_forest
    from forestslam.sim.stand import load_stand
    from forestslam.sim.styles import apply_style
    from forestslam.sim.terrain import make_terrain

    stem_cfg = from_dict(StemConfig, apply_style({"style": style}).get("stems", {}))
    stand = load_stand(StandConfig(size_m=(40, 40), min_spacing_m=3.0, density_per_ha=150), seed=4)
    terrain = make_terrain(
        TerrainConfig(relief_m=1.0, roughness_m=0.03), stand.bounds, np.random.default_rng(1)
    )
    clutter = ClutterConfig(branches_per_tree=0, shrubs_per_ha=0, logs_per_ha=0)
    forest = build_forest(stand, terrain, stem_cfg, clutter, None, 9)
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
    az = np.linspace(0, 2 * np.pi, 1440, endpoint=False)
    out = np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)])
    gaps = []
    for i in range(0, len(t["id"]), max(1, len(t["id"]) // 10)):
        centre = np.array([t["x"][i], t["y"][i], t["z_ground"][i] + BREAST_HEIGHT_M])
        origins = centre + 1.0 * out
        hit = scene.cast(origins, -out, 0.0, 5.0, 0)
        rng_, surface, obj = hit.range, hit.surface, hit.object
        assert (obj == i).all() and (surface == STEM).all()
        hits = origins[:, :2] - rng_[:, None] * out[:, :2]
        girth = ConvexHull(hits).area / np.pi
        assert girth == pytest.approx(t["dbh_m"][i], abs=2e-4)
        gaps.append(t["dbh_m"][i] - 2 * np.linalg.norm(hits - centre[:2], axis=1).mean())
    # The tape lies on the bark ridges: the mean radial diameter is smaller, by about a bark
    # amplitude or more (polygon faces).
    assert np.min(gaps) > 0.0005
    # Scaled so that the measured girth is the stand's DBH.
    np.testing.assert_allclose(t["dbh_m"], stand.dbh, atol=1e-5)
