"""Simulator output: bag/mcap read back through forestslam.io, truth files, determinism, CLI."""

from __future__ import annotations

import numpy as np
import pytest

core = pytest.importorskip("forestslam._core")
if not hasattr(core, "SimScene"):
    pytest.skip("forestslam._core built without the simulator", allow_module_level=True)

from forestslam.errors import InputError  # noqa: E402
from forestslam.io import read_scans, read_trees_csv, read_tum  # noqa: E402
from forestslam.sim import load_scenario, simulate  # noqa: E402
from forestslam.sim.forest import GROUND  # noqa: E402
from forestslam.sim.simulate import scan_at  # noqa: E402
from forestslam.sim.world import build_world  # noqa: E402

N = 4


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "a"
    simulate("sample", out, max_scans=N)
    return out


def test_bag_reads_back_with_counts_fields_and_stamps(sample_run):
    scans = list(read_scans(sample_run / "sequence.bag"))
    assert len(scans) == N
    cfg = load_scenario("sample", max_scans=N)
    world = build_world(cfg)
    stamps, poses = read_tum(sample_run / "truth" / "trajectory.tum")
    assert len(stamps) == N
    for k, scan in enumerate(scans):
        expected = scan_at(world, k)
        assert scan.stamp == pytest.approx(cfg.motion.start_time_s + 0.1 * k, abs=1e-6)
        assert stamps[k] == pytest.approx(scan.stamp, abs=1e-6)
        assert len(scan) == len(expected) > 10000
        assert scan.intensity is not None and scan.ring is not None and scan.time is not None
        np.testing.assert_allclose(scan.points, expected.points, atol=1e-5)  # float32 in the bag
        np.testing.assert_array_equal(scan.ring, expected.ring)
        np.testing.assert_allclose(scan.time, expected.time, atol=1e-6)
        assert scan.time.min() >= 0 and scan.time.max() < 0.1
        assert set(np.unique(scan.ring)) <= set(range(16))
    np.testing.assert_allclose(poses, world.trajectory.poses(world.stamps), atol=1e-6)


def test_truth_files(sample_run):
    trees = read_trees_csv(sample_run / "truth" / "trees.csv")
    assert list(trees) == ["id", "x", "y", "z_ground", "dbh_m", "height_m"]
    assert len(trees["id"]) > 50
    assert (trees["dbh_m"] > 0.05).all() and (trees["height_m"] > trees["dbh_m"]).all()
    text = (sample_run / "truth" / "scenario.yaml").read_text()
    cfg = load_scenario(sample_run / "truth" / "scenario.yaml")  # reloadable as a scenario
    assert cfg.seed == 7 and cfg.motion.max_scans == N and "derived:" in text


def test_same_seed_same_bytes_other_seed_differs(sample_run, tmp_path):
    simulate("sample", tmp_path / "b", max_scans=N)
    for rel in ("sequence.bag", "truth/trajectory.tum", "truth/trees.csv", "truth/scenario.yaml"):
        assert (sample_run / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    simulate("sample", tmp_path / "c", max_scans=1, seed=8)
    a = next(iter(read_scans(sample_run / "sequence.bag")))
    c = next(iter(read_scans(tmp_path / "c" / "sequence.bag")))
    assert len(a) != len(c) or not np.allclose(a.points, c.points)


def test_mcap_format(tmp_path):
    simulate("sample", tmp_path, max_scans=2, format="mcap")
    scans = list(read_scans(tmp_path / "sequence.mcap"))
    assert len(scans) == 2 and scans[1].stamp - scans[0].stamp == pytest.approx(0.1, abs=1e-6)


def test_points_are_in_the_sensor_frame_at_their_own_time():
    # Fast straight drive over flat ground: moved by the pose at their own time, ground points
    # land on the ground; the sweep-start pose puts them off by speed * time along the heading.
    speed = 1.5
    cfg = load_scenario(
        "sample",
        path="line",
        length_m=20.0,
        speed=speed,
        max_scans=3,
        terrain__relief_m=0.0,
        terrain__roughness_m=0.0,
        motion__vibration_deg=0.0,
        motion__vibration_z_m=0.0,
        stand__density_per_ha=0.0,
    )
    world = build_world(cfg)
    assert len(world.stand) == 0
    scan, surface, _ = scan_at(world, 2, labels=True)
    g = surface == GROUND
    assert g.sum() > 5000
    poses = world.trajectory.poses(world.stamps[2] + scan.time[g])
    own = np.einsum("nij,nj->ni", poses[:, :3, :3], scan.points[g]) + poses[:, :3, 3]
    start = world.trajectory.poses(world.stamps[2:3])[0]
    at_start = scan.points[g] @ start[:3, :3].T + start[:3, 3]
    sigma = world.noise.range_noise_m  # the simulated sensor's, not the profile's nominal one
    ground_z = world.terrain.height_at(own[:, :2])
    assert np.abs(own[:, 2] - ground_z).max() < 6 * sigma
    assert abs(np.mean(own[:, 2] - ground_z)) < 0.2 * sigma
    heading = start[:3, 0] / np.linalg.norm(start[:3, 0])
    expected = speed * scan.time[g][:, None] * heading[None, :]
    np.testing.assert_allclose(own - at_start, expected, atol=1e-6)
    assert scan.time[g].max() > 0.09  # so the offsets reach about 0.14 m


def test_bad_inputs_raise_input_error(tmp_path):
    with pytest.raises(InputError, match="unknown scenario"):
        simulate("no-such-scenario", tmp_path)
    with pytest.raises(InputError, match="unknown sensor"):
        simulate("sample", tmp_path, sensor="vlp99")
    with pytest.raises(InputError, match="unknown key"):
        simulate("sample", tmp_path, terrain__bumpiness=3)
    with pytest.raises(InputError, match="static station"):
        simulate("sample", tmp_path, sensor="tls")
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="x,y,dbh_m"):
        simulate("sample", tmp_path, stand=str(bad))
    with pytest.raises(InputError, match="format"):
        simulate("sample", tmp_path, format="pcap")


def test_cli_with_preview(tmp_path, capsys):
    from forestslam.cli.main import app

    app(
        [
            "simulate",
            "--scenario",
            "sample",
            "--max-scans",
            "2",
            "--seed",
            "3",
            "--preview",
            "--out",
            str(tmp_path),
        ],
        standalone_mode=False,
    )
    printed = capsys.readouterr().out
    assert "2 scans" in printed
    assert (tmp_path / "preview.png").stat().st_size > 10000
    assert (tmp_path / "sequence.bag").is_file()
