"""Simulator world: stands (CSV, crop, generated), allometry, paths clear of stems, terrain, TLS
station output and the shared world of tls-plot / mls-plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.sim.config import MotionConfig, StandConfig, TerrainConfig
from forestslam.sim.motion import plan_path, stem_clearance
from forestslam.sim.stand import heights_from_dbh, load_stand
from forestslam.sim.terrain import make_terrain

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def test_stand_from_csv_with_and_without_heights_and_crop(tmp_path):
    csv = tmp_path / "s.csv"
    csv.write_text("x,y,dbh_m\n1,2,0.2\n10,12,0.35\n30,5,0.5\n4,4,nan\n")
    stand = load_stand(str(csv))
    assert len(stand) == 3  # the NaN row is skipped
    np.testing.assert_allclose(stand.dbh, [0.2, 0.35, 0.5])
    # Heights from the Naslund curve (with 5 % noise by default): check the curve itself.
    np.testing.assert_allclose(heights_from_dbh([0.3], 1.0, 0.18), [1.3 + (30 / 6.4) ** 2])
    assert np.all(np.abs(np.log(stand.height / heights_from_dbh(stand.dbh, 1.0, 0.18))) < 0.25)
    cropped = load_stand(str(csv), crop_m=(0, 0, 15, 15))
    assert len(cropped) == 2 and cropped.bounds == (0, 0, 15, 15)
    with_h = tmp_path / "h.csv"
    with_h.write_text("x,y,dbh_m,height_m\n1,2,0.2,17.5\n")
    assert load_stand(str(with_h)).height[0] == 17.5
    with pytest.raises(InputError, match="not found"):
        load_stand(str(tmp_path / "missing.csv"))
    with pytest.raises(InputError, match="crop"):
        load_stand(str(csv), crop_m=(5, 5, 1, 1))


@pytest.mark.parametrize("process", ["clustered", "regular", "poisson"])
def test_generated_stand_respects_density_spacing_and_dbh(process):
    cfg = StandConfig(process=process, size_m=(80, 60), density_per_ha=300, min_spacing_m=2.0)
    stand = load_stand(cfg, seed=3)
    expected = 300 * 0.48
    assert abs(len(stand) - expected) < 0.15 * expected
    from scipy.spatial import cKDTree

    if process != "regular":  # the jittered grid is regular by construction
        d, _ = cKDTree(stand.xy).query(stand.xy, k=2)
        assert d[:, 1].min() >= 2.0
    assert stand.dbh.min() >= cfg.dbh_min_m and stand.dbh.max() <= cfg.dbh_max_m
    assert abs(stand.dbh.mean() - cfg.dbh_mean_m) < 0.03
    again = load_stand(cfg, seed=3)
    np.testing.assert_array_equal(again.xy, stand.xy)


@pytest.mark.parametrize("path", ["loop", "lawnmower", "line"])
def test_paths_keep_clear_of_stems(path):
    stand = load_stand(StandConfig(size_m=(80, 80), density_per_ha=400, min_spacing_m=2.5), seed=1)
    cfg = MotionConfig(path=path, length_m=120.0, stem_clearance_m=1.2, lane_spacing_m=10.0)
    planned = plan_path(cfg, stand)
    assert stem_clearance(planned.xy, stand).min() >= 0.9 * 1.2
    assert planned.length_m == pytest.approx(120.0, rel=0.15)
    assert planned.closed == (path == "loop")
    # No cusps: no step of 0.25 m turns by more than 40 degrees (lawnmower ends included).
    pts = np.vstack([planned.xy, planned.xy[:2]]) if planned.closed else planned.xy
    step = np.diff(pts, axis=0)
    turn = np.abs(np.diff(np.unwrap(np.arctan2(step[:, 1], step[:, 0]))))
    assert np.degrees(turn).max() < 40.0


def test_waypoint_file_and_station(tmp_path):
    stand = load_stand(StandConfig(size_m=(40, 40), density_per_ha=200), seed=2)
    way = tmp_path / "w.csv"
    way.write_text("x,y\n5,5\n35,5\n35,35\n")
    planned = plan_path(MotionConfig(path=str(way)), stand)
    assert not planned.static and planned.length_m > 55
    station = tmp_path / "station.csv"
    station.write_text("x,y\n20.5,20.5\n")
    assert plan_path(MotionConfig(path=str(station)), stand).static
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="x,y"):
        plan_path(MotionConfig(path=str(bad)), stand)


def test_terrain_relief_and_roughness():
    cfg = TerrainConfig(relief_m=1.5, relief_wavelength_m=50.0, roughness_m=0.0, margin_m=10)
    t = make_terrain(cfg, (0, 0, 100, 100), np.random.default_rng(0))
    inner = t.height_at(
        np.stack(np.meshgrid(np.arange(0, 100.1, 0.5), np.arange(0, 100.1, 0.5)), -1).reshape(-1, 2)
    )
    assert inner.max() == pytest.approx(1.5, abs=0.01) and inner.min() == pytest.approx(
        -1.5, abs=0.01
    )
    rough = make_terrain(
        TerrainConfig(relief_m=0.0, roughness_m=0.03), (0, 0, 50, 50), np.random.default_rng(0)
    )
    assert np.std(rough.z) == pytest.approx(0.03, rel=0.05)


core = pytest.importorskip("forestslam._core")


def test_terrain_heights_agree_with_ray_caster():
    t = make_terrain(
        TerrainConfig(relief_m=1.0, roughness_m=0.05), (0, 0, 30, 30), np.random.default_rng(5)
    )
    scene = core.SimScene(
        t.x0, t.y0, t.cell, t.z, np.zeros((0, 12)), np.zeros((0, 8)), np.zeros((0, 8))
    )
    xy = np.random.default_rng(1).uniform(0, 30, (500, 2))
    np.testing.assert_allclose(scene.height_at(xy), t.height_at(xy), atol=1e-12)
    # Vertical rays from above land exactly on the same surface.
    origins = np.column_stack([xy, np.full(len(xy), 10.0)])
    hit = scene.cast(origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1)), 0.0, 50.0, 0)
    r, surface = hit.range, hit.surface
    np.testing.assert_allclose(10.0 - r, t.height_at(xy), atol=1e-9)
    assert (surface == 1).all()


def test_tls_station_writes_reference_in_station_frame(tmp_path):
    from forestslam.io import read_cloud, read_tum
    from forestslam.sim import simulate

    profile = tmp_path / "tls-coarse.yaml"
    profile.write_text(
        "name: tls-coarse\nkind: tls\nchannels: 150\nvertical_fov_deg: [-60.0, 90.0]\n"
        "horizontal_fov_deg: 360.0\nazimuth_resolution_deg: 1.0\nrate_hz: 0.0\nrange_min_m: 0.6\n"
        "range_max_m: 120.0\nrange_noise_m: 0.002\ndropout_rate: 0.0\nimage_rows: 150\n"
        "image_cols: 360\nintensity_threshold: 100.0\n"
    )
    station = tmp_path / "station.csv"
    station.write_text("x,y\n30,30\n")
    out = simulate("sample", tmp_path / "tls", sensor=str(profile), path=str(station))
    cloud = read_cloud(out / "reference.laz")
    assert 20000 < len(cloud) <= 150 * 360
    stamps, poses = read_tum(out / "truth" / "trajectory.tum")
    assert len(stamps) == 1
    np.testing.assert_allclose(poses[0, :2, 3], [30, 30], atol=1e-9)
    np.testing.assert_allclose(poses[0, :3, :3], np.eye(3), atol=1e-12)  # levelled tripod
    # Station frame: the ground below is about 1 m (sample sensor height) under the origin.
    below = cloud.points[np.hypot(cloud.points[:, 0], cloud.points[:, 1]) < 2.0]
    assert np.median(below[:, 2]) == pytest.approx(-1.0, abs=0.1)
    assert not (out / "sequence.bag").exists()


@pytest.mark.skipif(
    not (SHARED / "stands" / "spruces.csv").is_file(), reason="needs ../shared/data"
)
def test_tls_plot_and_mls_plot_share_one_world():
    from forestslam.sim import load_scenario
    from forestslam.sim.world import build_world

    tls = build_world(load_scenario("tls-plot"))
    mls = build_world(load_scenario("mls-plot"))
    for key in tls.forest.trees:
        np.testing.assert_array_equal(tls.forest.trees[key], mls.forest.trees[key])
    np.testing.assert_array_equal(tls.forest.stems, mls.forest.stems)
    np.testing.assert_array_equal(tls.forest.cylinders, mls.forest.cylinders)
    np.testing.assert_array_equal(tls.forest.foliage, mls.forest.foliage)
    np.testing.assert_array_equal(tls.terrain.z, mls.terrain.z)
    assert tls.path.static and not mls.path.static
    assert 40 <= len(tls.stand) <= 80
    # The walk stays in the plot (within 1.5 m of its edges, after moving around stems) and
    # crosses it.
    x0, y0, x1, y1 = tls.stand.bounds
    assert (mls.path.xy[:, 0] > x0 - 1.5).all() and (mls.path.xy[:, 0] < x1 + 1.5).all()
    assert (mls.path.xy[:, 1] > y0 - 1.5).all() and (mls.path.xy[:, 1] < y1 + 1.5).all()
    assert np.ptp(mls.path.xy[:, 1]) > 15 and np.ptp(mls.path.xy[:, 0]) > 15


def test_short_loops_keep_their_length_when_pushed_clear_of_stems():
    # Smoothing a small loop used to shrink it to a point (a sequence standing still).
    from forestslam.sim import load_scenario
    from forestslam.sim.motion import _polyline_length, plan_path
    from forestslam.sim.stand import load_stand

    for length_m in (10.0, 14.0, 45.0):
        cfg = load_scenario("sample", length_m=length_m)
        path = plan_path(cfg.motion, load_stand(cfg.stand, seed=int(cfg.seed)))
        assert _polyline_length(path.xy, path.closed) >= 0.8 * length_m
