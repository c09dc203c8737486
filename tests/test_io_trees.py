"""Tree maps: CSV and GeoJSON writers round-trip, NaN handling, bad columns."""

from __future__ import annotations

import json

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import read_trees_csv, write_trees_csv, write_trees_geojson


@pytest.fixture
def trees():
    rng = np.random.default_rng(8)
    k = 25
    return {
        "id": np.arange(k),
        "x": rng.uniform(-50, 50, k),
        "y": rng.uniform(-50, 50, k),
        "z": rng.uniform(-1, 1, k),
        "dbh_m": np.where(rng.random(k) < 0.2, np.nan, rng.uniform(0.1, 0.6, k)),
        "observations": rng.integers(1, 40, k),
    }


def test_csv_round_trip(tmp_path, trees):
    path = tmp_path / "out" / "trees.csv"
    write_trees_csv(path, trees)
    lines = path.read_text().splitlines()
    assert lines[0] == "id,x,y,z,dbh_m,observations" and len(lines) == 26
    assert lines[1].split(",")[0] == "0" and "." not in lines[1].split(",")[-1]  # ints stay ints
    back = read_trees_csv(path)
    assert list(back) == list(trees)
    for name, values in trees.items():
        np.testing.assert_allclose(back[name], values, atol=5e-7, equal_nan=True)
    assert np.isnan(back["dbh_m"]).sum() == np.isnan(trees["dbh_m"]).sum() > 0


def test_csv_empty_and_errors(tmp_path, trees):
    write_trees_csv(tmp_path / "empty.csv", {"id": [], "x": [], "y": []})
    back = read_trees_csv(tmp_path / "empty.csv")
    assert list(back) == ["id", "x", "y"] and len(back["x"]) == 0
    with pytest.raises(InputError, match="differ in length"):
        write_trees_csv(tmp_path / "bad.csv", {"x": [1.0, 2.0], "y": [1.0]})
    assert not (tmp_path / "bad.csv").exists()
    (tmp_path / "ragged.csv").write_text("x,y\n1,2\n3\n")
    with pytest.raises(InputError, match="ragged.csv"):
        read_trees_csv(tmp_path / "ragged.csv")
    with pytest.raises(InputError, match="not found"):
        read_trees_csv(tmp_path / "absent.csv")


def test_geojson(tmp_path, trees):
    path = tmp_path / "trees.geojson"
    write_trees_geojson(path, trees)
    doc = json.loads(path.read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 25
    for i, feature in enumerate(doc["features"]):
        assert feature["geometry"]["type"] == "Point"
        np.testing.assert_allclose(
            feature["geometry"]["coordinates"],
            [trees["x"][i], trees["y"][i], trees["z"][i]],
            atol=1e-6,
        )
        props = feature["properties"]
        assert set(props) == {"id", "dbh_m", "observations"} and props["id"] == i
        if np.isnan(trees["dbh_m"][i]):
            assert props["dbh_m"] is None  # valid JSON, no NaN literal
        else:
            assert props["dbh_m"] == pytest.approx(trees["dbh_m"][i])
    with pytest.raises(InputError, match="need x and y"):
        write_trees_geojson(tmp_path / "b.geojson", {"id": [1]})


@pytest.mark.parametrize("scale, unit", [(100.0, "centimetres"), (1000.0, "millimetres")])
def test_dbh_m_column_in_other_units_is_refused(tmp_path, scale, unit):
    rng = np.random.default_rng(3)
    n = 30
    cols = {"x": rng.uniform(0, 50, n), "y": rng.uniform(0, 50, n)}
    cols["dbh_m"] = rng.uniform(0.1, 0.6, n)
    write_trees_csv(tmp_path / "m.csv", cols)
    assert read_trees_csv(tmp_path / "m.csv")["dbh_m"].max() < 1  # metres pass
    cols["dbh_m"] = cols["dbh_m"] * scale
    write_trees_csv(tmp_path / "cm.csv", cols)
    with pytest.raises(InputError, match=f"dbh_m has a median of .* looks like {unit}"):
        read_trees_csv(tmp_path / "cm.csv")


def test_a_binary_file_is_not_a_tree_csv(tmp_path):
    (tmp_path / "t.csv").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(InputError, match="t.csv: not a tree CSV .not UTF-8"):
        read_trees_csv(tmp_path / "t.csv")
