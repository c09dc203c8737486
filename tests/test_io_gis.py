"""GIS outputs read back by independent readers (laspy, sqlite3, pyogrio) with their CRS, and
UTM-sized coordinates kept to the millimetre."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.georef import Georeference, parse_georef
from forestslam.io.gis import write_map_laz, write_trees_gpkg
from forestslam.io.trees import write_trees_geojson

UTM_12N = "EPSG:32612"


@pytest.fixture
def utm_points():
    rng = np.random.default_rng(5)
    local = rng.uniform([-30, -30, -2], [30, 30, 15], size=(2000, 3))
    georef = Georeference.from_options(UTM_12N, "512345.6789,5123456.7891,1523.25,33.0")
    return local, georef


def test_georef_moves_local_points_into_the_crs():
    T = parse_georef("500000,5000000,100,90")
    p = Georeference("EPSG:32612", T).points([[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(p, [[500000.0, 5000001.0, 100.0]], atol=1e-9)


@pytest.mark.parametrize(
    "crs, georef, message",
    [
        ("EPSG:4326", None, "not a projected CRS"),
        ("EPSG:999999", None, "unknown coordinate reference system"),
        (None, "1,2,3,4", "needs --crs"),
        (UTM_12N, "1,2,3", "four numbers"),
        (UTM_12N, "1,2,nan,4", "four numbers"),
    ],
)
def test_bad_georeference_is_a_clear_error(crs, georef, message):
    with pytest.raises(InputError, match=message):
        Georeference.from_options(crs, georef)


def test_map_laz_round_trip_keeps_millimetres_classes_ids_and_crs(tmp_path, utm_points):
    import laspy

    local, georef = utm_points
    pts = georef.points(local)
    assert pts[:, 1].min() > 1e6
    classes = np.where(local[:, 2] < 0, 2, 1)
    tree_id = np.where(local[:, 2] > 10, 7, 0)
    gps_time = 1.7e9 + np.arange(len(pts)) * 1e-3
    path = tmp_path / "map.laz"
    write_map_laz(path, pts, classes, tree_id, gps_time, georef.pyproj_crs())
    las = laspy.read(path)
    assert las.header.version == laspy.header.Version(1, 4)
    assert las.header.point_format.id == 6
    np.testing.assert_allclose(las.header.scales, 0.001)
    back = np.column_stack([las.x, las.y, las.z])
    assert np.abs(back - pts).max() <= 0.0005 + 1e-9  # 1 mm scale: half a millimetre at most
    assert np.array_equal(las.classification, classes)
    assert np.array_equal(las.tree_id, tree_id)
    # Unix 1.7e9 = Tue 2023-11-14 22:13:20 UTC: GPS week 2288 (from Sunday the 12th), 2 days,
    # 80000 s and 18 leap seconds into it; adjusted standard GPS time subtracts 1e9
    np.testing.assert_allclose(las.gps_time - las.gps_time[0], gps_time - gps_time[0], atol=1e-6)
    assert las.gps_time[0] == pytest.approx(2288 * 604800 + 2 * 86400 + 80018 - 1e9, abs=1e-6)
    assert las.header.global_encoding.gps_time_type
    assert las.header.parse_crs().to_epsg() == 32612


def test_trees_gpkg_read_back_with_its_srs(tmp_path, utm_points):
    from pyogrio import read_info
    from pyogrio.raw import read

    local, georef = utm_points
    xy = georef.xy(local[:5, :2])
    table = {
        "id": np.arange(5),
        "x": xy[:, 0],
        "y": xy[:, 1],
        "dbh_m": np.array([0.2, 0.31, np.nan, 0.4, 0.25]),
        "observations": np.array([3, 10, 1, 7, 2]),
        "status": np.array(["new", "updated", "new", "updated", "updated"]),
    }
    path = tmp_path / "trees.gpkg"
    write_trees_gpkg(path, table, georef.pyproj_crs())
    with sqlite3.connect(path) as db:
        (srs,) = db.execute(
            "SELECT organization_coordsys_id FROM gpkg_spatial_ref_sys s JOIN "
            "gpkg_geometry_columns g ON g.srs_id = s.srs_id WHERE g.table_name = 'trees'"
        ).fetchone()
    assert srs == 32612
    info = read_info(path, layer="trees")
    assert info["features"] == 5 and info["geometry_type"] == "Point"
    _meta, _fids, geometry, fields = read(path, layer="trees")
    coords = np.array([np.frombuffer(g[-16:], dtype="<f8") for g in geometry])
    assert np.abs(coords - xy).max() < 1e-6
    names = list(_meta["fields"])
    assert np.isnan(fields[names.index("dbh_m")][2])
    assert list(fields[names.index("status")]) == list(table["status"])


def test_geojson_names_its_crs(tmp_path, utm_points):
    local, georef = utm_points
    xy = georef.xy(local[:3, :2])
    path = tmp_path / "trees.geojson"
    write_trees_geojson(path, {"x": xy[:, 0], "y": xy[:, 1]}, georef.ogc_urn())
    data = json.loads(path.read_text())
    assert data["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32612"
    coords = np.array([f["geometry"]["coordinates"] for f in data["features"]])
    assert np.abs(coords - xy).max() < 1e-6
