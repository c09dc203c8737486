"""Simulator measurement models: intensity per material (independent of any pipeline threshold),
range noise and dropouts per sensor, and the world styles."""

from __future__ import annotations

import numpy as np
import pytest

core = pytest.importorskip("forestslam._core")
if not hasattr(core, "SimScene"):
    pytest.skip("forestslam._core built without the simulator", allow_module_level=True)

from forestslam.errors import InputError  # noqa: E402
from forestslam.sim import load_scenario  # noqa: E402
from forestslam.sim.forest import FOLIAGE, GROUND, STEM  # noqa: E402
from forestslam.sim.simulate import scan_at  # noqa: E402
from forestslam.sim.world import build_world  # noqa: E402

QUICK = {"max_scans": 4}


def _labelled(world, scans=(0, 2)):
    parts = [scan_at(world, k, labels=True) for k in scans]
    scan = parts[0][0]
    pts = np.vstack([p[0].points for p in parts])
    inten = np.concatenate([p[0].intensity for p in parts])
    surface = np.concatenate([p[1] for p in parts])
    obj = np.concatenate([p[2] for p in parts])
    return scan, pts, inten, surface, obj


def test_intensity_does_not_depend_on_the_profiles_threshold(tmp_path):
    """The pipeline's intensity threshold is the pipeline's business: a profile that differs only
    in its threshold gives the very same intensities."""
    import yaml

    from forestslam.sensors import load_profile

    doc = load_profile("vlp16").to_dict()
    doc["intensity_threshold"] = 30.0
    other = tmp_path / "vlp16.yaml"  # same name: same simulated sensor model
    other.write_text(yaml.safe_dump(doc))
    a = scan_at(build_world(load_scenario("sample", **QUICK)), 1)
    b = scan_at(build_world(load_scenario("sample", sensor=str(other), **QUICK)), 1)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.intensity, b.intensity)


@pytest.mark.parametrize("style", ["a", "b"])
def test_intensity_per_material_overlaps_a_little_and_falls_off(style):
    world = build_world(load_scenario("sample", style=style, **QUICK))
    _, pts, inten, surface, _ = _labelled(world)
    assert np.all(inten == np.round(inten)) and inten.min() >= 0 and inten.max() <= 255
    r = np.linalg.norm(pts, axis=1)
    bark, leaf, ground = inten[surface == STEM], inten[surface == FOLIAGE], inten[surface == GROUND]
    assert len(bark) > 500 and len(leaf) > 100 and len(ground) > 1000
    # Foliage brighter than bark, bark brighter than (grazing) ground, but the distributions
    # overlap: some bark is brighter than the darkest quarter of the foliage.
    assert np.median(leaf) > 1.5 * np.median(bark) > 1.5 * np.median(ground)
    overlap = np.mean(bark > np.percentile(leaf, 25))
    assert 0.002 < overlap < 0.2
    # Range fall-off: far foliage is darker than near foliage.
    r_leaf = r[surface == FOLIAGE]
    near, far = r_leaf < np.percentile(r_leaf, 30), r_leaf > np.percentile(r_leaf, 70)
    assert np.median(leaf[far]) < 0.95 * np.median(leaf[near])


def test_bark_is_darker_at_oblique_incidence():
    """Bark returns are Lambertian-like: the stems' silhouette edges are darker than their
    fronts. Measured on a world without range fall-off, as the ratio of the medians."""
    cfg = load_scenario("sample", intensity__range_exponent=0.0, **QUICK)
    world = build_world(cfg)
    scan, surface, obj = scan_at(world, 1, labels=True)
    stem = surface == STEM
    pts, inten, tree = scan.points[stem], scan.intensity[stem], obj[stem]
    # Per tree, the points nearest the sensor face it; those at the largest bearing offset are
    # at the silhouette.
    front, edge = [], []
    bearing = np.arctan2(pts[:, 1], pts[:, 0])
    for t in np.unique(tree):
        m = tree == t
        if m.sum() < 20:
            continue
        off = np.abs(np.angle(np.exp(1j * (bearing[m] - np.median(bearing[m])))))
        order = np.argsort(off)
        k = max(3, m.sum() // 5)
        front.extend(inten[m][order[:k]])
        edge.extend(inten[m][order[-k:]])
    assert np.median(edge) < 0.8 * np.median(front)


def _ground_range_residuals(sensor: str, sigma: float) -> np.ndarray:
    """Range errors of ground returns in a flat, empty world, divided by the standard deviation
    the sensor model gives them: sigma at normal incidence and the beam footprint's spread."""
    cfg = load_scenario(
        "sample",
        sensor=sensor,
        max_scans=2,
        terrain__relief_m=0.0,
        terrain__roughness_m=0.0,
        motion__vibration_deg=0.0,
        motion__vibration_z_m=0.0,
        stand__density_per_ha=0.0,
    )
    world = build_world(cfg)
    scan, surface, _ = scan_at(world, 1, labels=True)
    g = surface == GROUND
    poses = world.trajectory.poses(world.stamps[1] + scan.time[g])
    d = np.einsum("nij,nj->ni", poses[:, :3, :3], scan.points[g])
    r = np.linalg.norm(d, axis=1)
    down = -d[:, 2] / r  # |cos incidence| on flat ground
    z0 = world.terrain.height_at(poses[:, :2, 3])
    true_r = (poses[:, 2, 3] - z0) / down
    c = np.clip(down, 0.0995, 1.0)
    div = world.noise.beam_divergence_mrad * 1e-3
    expected = np.hypot(sigma, 0.5 * div * true_r * np.sqrt(1 - c * c) / c)
    steep = down > 0.2
    return ((r - true_r) / expected)[steep]


@pytest.mark.parametrize(("sensor", "sigma"), [("vlp16", 0.03), ("hdl32", 0.02)])
def test_range_noise_per_sensor_profile(sensor, sigma):
    """The simulated sensor's own noise (data sheet: VLP-16 3 cm, HDL-32E 2 cm), not the
    profile's nominal value, plus the footprint's spread on inclined ground."""
    z = _ground_range_residuals(sensor, sigma)
    assert len(z) > 2000
    assert abs(np.mean(z)) < 0.1
    assert np.std(z) == pytest.approx(1.0, abs=0.05)


def test_sensor_noise_table_and_overrides():
    from forestslam.sensors import load_profile
    from forestslam.sim.config import SensorConfig
    from forestslam.sim.sensor_model import sensor_noise

    assert sensor_noise(load_profile("tls"), SensorConfig()).range_noise_m == 0.002
    assert sensor_noise(load_profile("vlp16"), SensorConfig()).range_noise_m == 0.03
    over = sensor_noise(load_profile("vlp16"), SensorConfig(range_noise_m=0.01, dropout_rate=0.1))
    assert (over.range_noise_m, over.dropout_rate) == (0.01, 0.1)
    with pytest.raises(InputError, match="dropout_rate"):
        sensor_noise(load_profile("vlp16"), SensorConfig(dropout_rate=1.5))


def test_styles_differ_and_are_set_by_scenario_or_override(tmp_path):
    a = load_scenario("sample")
    b = load_scenario("sample", style="b")
    assert a.style == "a" and b.style == "b"
    assert a.stems.polygon_sides == (0, 0) and b.stems.polygon_sides[0] >= 3
    assert a.intensity.bark.median != b.intensity.bark.median
    # A key the scenario sets wins over the style's preset.
    c = load_scenario("sample", style="b", stems__bark_amplitude_m=0.001)
    assert c.stems.bark_amplitude_m == 0.001 and c.stems.polygon_sides == b.stems.polygon_sides
    f = tmp_path / "s.yaml"
    f.write_text("style: b\nstand:\n  size_m: [30.0, 30.0]\n")
    assert load_scenario(f).clutter.crown_clumps == b.clutter.crown_clumps
    with pytest.raises(InputError, match="style"):
        load_scenario("sample", style="c")
    with pytest.raises(InputError, match="style"):
        load_scenario(a, style="b")
    wa, wb = build_world(load_scenario("sample", **QUICK)), build_world(b)
    sa, sb = wa.forest.stems, wb.forest.stems
    assert (sa[:, 15] == 0).all() and (sb[:, 15] >= 9).all()
    # Same stand, same truth DBH (the girth is scaled to the stand's), other shapes.
    np.testing.assert_allclose(wa.forest.trees["dbh_m"], wb.forest.trees["dbh_m"], atol=1e-5)


def test_same_seed_same_bytes_for_both_styles():
    for style in ("a", "b"):
        cfg = load_scenario("sample", style=style, **QUICK)
        s1, s2 = scan_at(build_world(cfg), 3), scan_at(build_world(cfg), 3)
        assert s1.points.tobytes() == s2.points.tobytes()
        assert s1.intensity.tobytes() == s2.intensity.tobytes()


def test_cli_style_option(tmp_path):
    """`forestslam simulate --style b` writes a style-b world (recorded in scenario.yaml); an
    unknown style is one readable line and a non-zero exit."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root / "python"), env.get("PYTHONPATH", "")])

    def cli(*args):
        cmd = [sys.executable, "-m", "forestslam.cli.main", "simulate", *args]
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)

    out = tmp_path / "b"
    done = cli("--scenario", "sample", "--style", "b", "--max-scans", "1", "--out", str(out))
    assert done.returncode == 0, done.stderr
    doc = yaml.safe_load((out / "truth" / "scenario.yaml").read_text())
    assert doc["style"] == "b" and doc["stems"]["polygon_sides"] == [9, 16]
    assert doc["derived"]["sim_model_version"] >= 2
    bad = cli("--scenario", "sample", "--style", "z", "--out", str(tmp_path / "z"))
    assert bad.returncode != 0 and "style" in bad.stderr and "Traceback" not in bad.stderr
