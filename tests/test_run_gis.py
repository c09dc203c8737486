"""A run's GIS outputs: in the CRS of --crs/--georef to the millimetre, read back by laspy,
sqlite3 and the GeoJSON's crs member; map.laz tree ids are trees.csv's."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
import yaml

from forestslam.georef import parse_georef
from forestslam.io import read_trees_csv, read_tum

GEOREF = "512345.678,5123456.789,410.5,30"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from forestslam.runner import run
    from forestslam.sim import simulate

    tmp = tmp_path_factory.mktemp("gis")
    seq = simulate("sample", tmp / "sim", length_m=14.0)
    run(seq / "sequence.bag", "vlp16", tmp / "local", progress=False)
    run(seq / "sequence.bag", None, tmp / "utm", progress=False, crs="EPSG:32633", georef=GEOREF)
    return tmp / "local", tmp / "utm"


def test_every_output_is_the_local_run_moved_into_the_crs(runs):
    import laspy

    local, utm = runs
    T = parse_georef(GEOREF)
    _, p_local = read_tum(local / "trajectory.tum")
    _, p_utm = read_tum(utm / "trajectory.tum")
    np.testing.assert_allclose(p_utm, np.einsum("ij,njk->nik", T, p_local), atol=1e-6)
    a, b = read_trees_csv(local / "trees.csv"), read_trees_csv(utm / "trees.csv")
    xyz = np.column_stack([a["x"], a["y"], a["z"]]) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(np.column_stack([b["x"], b["y"], b["z"]]), xyz, atol=1e-5)
    la, lb = laspy.read(local / "map.laz"), laspy.read(utm / "map.laz")
    pa = np.column_stack([la.x, la.y, la.z]) @ T[:3, :3].T + T[:3, 3]
    pb = np.column_stack([lb.x, lb.y, lb.z])
    assert len(pa) == len(pb) > 1000 and pb[:, 1].min() > 1e6
    # 1 mm scale on both sides: half a millimetre each, the local one rotated by 30 deg
    assert np.abs(pa - pb).max() <= 0.0005 * (np.cos(np.pi / 6) + np.sin(np.pi / 6)) + 0.0005
    assert lb.header.parse_crs().to_epsg() == 32633 and la.header.parse_crs() is None


def test_map_laz_labels_ground_and_the_trees_of_trees_csv(runs):
    import laspy

    _, utm = runs
    las = laspy.read(utm / "map.laz")
    assert las.header.point_format.id == 6 and las.header.version.minor == 4
    ids = set(np.unique(las.tree_id)) - {0}
    trees = set(read_trees_csv(utm / "trees.csv")["id"].astype(int))
    assert len(ids) >= 0.95 * len(trees) and ids <= trees
    assert (las.classification == 2).sum() > 1000


def test_gpkg_and_geojson_carry_the_crs(runs):
    _, utm = runs
    with sqlite3.connect(utm / "trees.gpkg") as db:
        (code,) = db.execute(
            "SELECT organization_coordsys_id FROM gpkg_spatial_ref_sys s JOIN "
            "gpkg_geometry_columns g ON g.srs_id = s.srs_id WHERE g.table_name = 'trees'"
        ).fetchone()
        (n,) = db.execute("SELECT count(*) FROM trees").fetchone()
    assert code == 32633 and n == len(read_trees_csv(utm / "trees.csv")["id"])
    geo = json.loads((utm / "trees.geojson").read_text())
    assert geo["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32633"
    meta = yaml.safe_load((utm / "run.yaml").read_text())
    assert meta["sensor"] == "vlp16" and meta["sensor_identified"]
    assert meta["output_frame"]["crs"] == "EPSG:32633"
