"""Perception on bad input: empty, all-NaN, one point, no ground, huge clouds, wrong shapes;
and the `forestslam detect` CLI end to end."""

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import Scan
from forestslam.perception import detect


@pytest.mark.parametrize(
    "points",
    [np.zeros((0, 3)), np.full((1000, 3), np.nan), np.array([[1.0, 2.0, 3.0]])],
    ids=["empty", "all-nan", "one-point"],
)
def test_degenerate_scans_give_empty_stems(points):
    for sensor in ("vlp16", "map"):
        stems = detect(Scan(0.0, points), sensor)
        assert len(stems) == 0
        assert stems.xy.shape == (0, 2) and stems.cov.shape == (0, 3, 3)


def test_no_ground_still_finds_a_stem():
    # A vertical pole of points (a stem seen from a tripod) with no ground at all.
    z = np.repeat(np.arange(0.0, 3.0, 0.1), 20)
    a = np.tile(np.linspace(-0.8, 0.8, 20), 30) + np.pi
    pts = np.c_[5 + 0.2 * np.cos(a), 0.2 * np.sin(a), z]
    stems = detect(pts, "map")
    assert len(stems) == 1
    assert stems.ground.shape == (0, 3)
    assert np.isfinite(stems.base_z).all()


def test_wrong_shapes_and_huge_clouds_are_clear_errors(monkeypatch):
    with pytest.raises(InputError):
        detect(np.zeros((10, 2)), "vlp16")
    with pytest.raises(InputError):
        detect(np.zeros((5, 3)), "no-such-sensor")
    import forestslam.perception.pipeline as d

    monkeypatch.setattr(d, "MAX_POINTS", 100)
    with pytest.raises(InputError, match="more than"):
        detect(np.zeros((101, 3)), "vlp16")


def test_two_million_points_do_not_crash():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-50, 50, (2_000_000, 3))
    pts[:, 2] = rng.normal(0, 0.02, len(pts))  # a huge flat field: ground only
    stems = detect(pts, "map")
    assert len(stems) == 0
    assert len(stems.ground) > 1000


def test_cli_detect_writes_csv_and_png(tmp_path):
    from typer.testing import CliRunner

    from forestslam.cli.main import app
    from forestslam.io import read_trees_csv, write_cloud
    from forestslam.perception.synthetic import synthetic_scan

    trees = np.array([[5.0, 0.0, 0.3], [0.0, -8.0, 0.45], [-6.0, 6.0, 0.2]])
    cloud = tmp_path / "scan.npy"
    write_cloud(cloud, synthetic_scan("vlp16", trees).points)
    out, png = tmp_path / "trees.csv", tmp_path / "view.png"
    res = CliRunner().invoke(
        app, ["detect", str(cloud), "--sensor", "vlp16", "--out", str(out), "--png", str(png)]
    )
    assert res.exit_code == 0, res.output
    table = read_trees_csv(out)
    assert list(table) == ["id", "x", "y", "z", "dbh_m"]
    assert len(table["id"]) == 3
    assert png.stat().st_size > 10_000
    res = CliRunner().invoke(
        app, ["detect", str(cloud), "--sensor", "vlp16", "--out", str(out), "--scan", "3"]
    )
    assert res.exit_code != 0
