"""Stems without ground (`map` clouds): a breast-height slice, a cropped trunk standing on its
lowest point, an explicit breast height; the real TreeScope trunk crops when present."""

import csv
import os
from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.perception import detect
from forestslam.perception.stems import BREAST_HEIGHT_SOURCES

DATA = (
    Path(
        os.environ.get(
            "FORESTSLAM_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
        )
    )
    / "trunks"
)


def rough_trunk(dbh, z0, z1, seed, centre=(3.0, -2.0), ovality=0.06, bark_m=0.004):
    """Dense points of an oval trunk section with bark roughness and 5 mm noise (a TLS crop)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, 6000)
    z = rng.uniform(z0, z1, a.size)
    r = 0.5 * dbh * (1 + ovality * np.cos(2 * a)) + bark_m * np.sin(17 * a)
    r += rng.normal(0, 0.005, a.size)
    return np.c_[centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), z]


def test_breast_height_slice_without_ground():
    for seed, dbh in enumerate((0.18, 0.31, 0.52)):
        stems = detect(rough_trunk(dbh, 1.1, 1.5, seed), "map")
        assert len(stems) == 1
        assert BREAST_HEIGHT_SOURCES[stems.breast_source[0]] == "slice middle"
        assert stems.dbh[0] == pytest.approx(dbh, abs=0.01)
        np.testing.assert_allclose(stems.xy[0], [3.0, -2.0], atol=0.01)
        assert stems.z[0] == pytest.approx(1.3, abs=0.01)


def test_trunk_without_ground_stands_on_its_lowest_point():
    # A stem cut out of a plot, 0.2-3 m, tapering: DBH is taken 1.3 m above its lowest point.
    pts = rough_trunk(0.3, 0.2, 3.0, 7)
    h = pts[:, 2] - 1.5
    pts[:, :2] = np.c_[3.0, -2.0] + (pts[:, :2] - [3.0, -2.0]) * (1 - 0.05 * h)[:, None]
    stems = detect(pts, "map")
    assert len(stems) == 1
    assert BREAST_HEIGHT_SOURCES[stems.breast_source[0]] in ("lowest point", "ground")
    assert stems.z[0] == pytest.approx(1.5, abs=0.05)
    assert stems.dbh[0] == pytest.approx(0.3, abs=0.01)
    explicit = detect(pts, "map", breast_height_z=2.5)
    assert BREAST_HEIGHT_SOURCES[explicit.breast_source[0]] == "explicit"
    assert explicit.z[0] == pytest.approx(2.5, abs=0.02)
    assert explicit.dbh[0] == pytest.approx(0.3 * (1 - 0.05), abs=0.01)
    with pytest.raises(InputError):
        detect(pts, "map", breast_height_z=float("nan"))


def test_no_circle_no_stem():
    rng = np.random.default_rng(0)
    flat = np.c_[rng.uniform(0, 1, 3000), rng.uniform(0, 0.02, 3000), rng.uniform(1.1, 1.5, 3000)]
    assert len(detect(flat, "map")) == 0


def test_real_trunks():
    field = DATA / "dbh_field.csv"
    if not field.is_file():
        pytest.skip(f"real data not available: {field}")
    from forestslam.io import read_cloud

    errors = []
    for row in csv.DictReader(field.open()):
        stems = detect(read_cloud(DATA / row["file"]).points, "map")
        assert len(stems) == 1, row["file"]
        errors.append(100 * stems.dbh[0] - float(row["dbh_cm"]))
    errors = np.array(errors)
    assert len(errors) == 16
    assert np.mean(np.abs(errors)) <= 1.0  # cm, field tape
    assert abs(np.mean(errors)) <= 0.5
