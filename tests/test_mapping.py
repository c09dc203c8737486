"""Tree map (windowed DBH fusion), voxel grid, ground map and DTM against known geometry."""

from types import SimpleNamespace

import numpy as np
import pytest

from forestslam.mapping import (
    GroundMap,
    MappingConfig,
    TreeMap,
    dtm_grid,
    voxel_downsample,
    write_dtm,
)


def test_voxel_downsample_centroids_and_counts():
    pts = np.array([[0.01, 0.01, 0.01], [0.09, 0.09, 0.09], [0.5, 0.5, 0.5], [np.nan, 0, 0]])
    c, n = voxel_downsample(pts, 0.1, return_counts=True)
    order = np.argsort(c[:, 0])
    np.testing.assert_allclose(c[order], [[0.05, 0.05, 0.05], [0.5, 0.5, 0.5]])
    assert n[order].tolist() == [2, 1]
    assert voxel_downsample(np.zeros((0, 3)), 0.1).shape == (0, 3)


def test_voxel_keys_of_a_large_cloud_in_blocks_equal_the_whole_formula():
    from forestslam.mapping.voxel import CHUNK_ROWS, finite_rows, voxel_keys

    rng = np.random.default_rng(3)
    pts = rng.normal(scale=40.0, size=(2 * CHUNK_ROWS + 17, 3)) + [5e5, 6e6, 300.0]
    origin = np.floor(pts.min(axis=0))
    idx = np.floor((pts - origin) / 0.1).astype(np.int64) + (1 << 20)
    whole = (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]
    np.testing.assert_array_equal(voxel_keys(pts, 0.1, origin), whole)
    with pytest.raises(ValueError, match="span more than"):
        voxel_keys(pts, 0.1)  # 6e6 m from the key origin: beyond 21 bits at 0.1 m
    pts[[5, CHUNK_ROWS + 3], [1, 2]] = [np.nan, np.inf]
    np.testing.assert_array_equal(finite_rows(pts), np.isfinite(pts).all(axis=1))


def test_dtm_of_a_plane_and_files(tmp_path):
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 10, size=(20000, 2))
    z = 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 2.0
    dtm = dtm_grid(np.column_stack([xy, z]), cell_m=0.5)
    assert dtm["z"].shape == (20, 20)
    gx = dtm["x0"] + np.arange(20) * 0.5
    gy = dtm["y0"] + np.arange(20) * 0.5
    expect = 0.1 * gx[None, :] - 0.05 * gy[:, None] + 2.0
    np.testing.assert_allclose(dtm["z"], expect, atol=0.01)  # cell mean of a plane
    write_dtm(tmp_path, dtm)
    back = np.load(tmp_path / "dtm.npz")
    np.testing.assert_allclose(back["z"], dtm["z"])
    rows = np.loadtxt(tmp_path / "dtm.csv", delimiter=",", skiprows=1)
    assert rows.shape == (400, 3)


def test_ground_map_uses_keyframe_poses():
    g = GroundMap(keyframe_voxel_m=0.2, voxel_m=0.2)
    local = np.column_stack(
        [
            np.repeat(np.arange(0, 2, 0.05), 40),
            np.tile(np.arange(0, 2, 0.05), 40),
            np.full(1600, -1.0),
        ]
    )
    g.add_keyframe(0, local)
    g.add_keyframe(1, local)
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [10.0, 0.0, 0.5]
    m = g.build(poses)
    assert len(m) == 200  # two 10x10 voxel patches
    assert np.isclose(m[m[:, 0] > 5, 2], -0.5).all() and np.isclose(m[m[:, 0] < 5, 2], -1).all()


def stem_scan(sensor_xy, centre, radius, rng, base_z=-1.0):
    """Points of the visible half of a vertical stem (sensor frame), band heights 1.0-1.6 m."""
    to_sensor = np.asarray(sensor_xy) - centre
    facing = np.arctan2(to_sensor[1], to_sensor[0])
    ang = facing + rng.uniform(-np.pi / 2.2, np.pi / 2.2, 120)
    r = radius + rng.normal(scale=0.008, size=120)
    world = np.column_stack(
        [
            centre[0] + r * np.cos(ang),
            centre[1] + r * np.sin(ang),
            base_z + rng.uniform(1.0, 1.6, 120),
        ]
    )
    return world - [sensor_xy[0], sensor_xy[1], 0.0]


def _pass_stem(tm, scan_dbh, n=40, tree_id=7):
    """A sensor passes a 30 cm stem at (5, 2) in n scans; scan_dbh(i): perception's DBH."""
    rng = np.random.default_rng(4)
    centre, radius = np.array([5.0, 2.0]), 0.15
    for i in range(n):
        sensor = np.array([0.1 * i, 0.0])
        T = np.eye(4)
        T[:2, 3] = sensor
        pts = stem_scan(sensor, centre, radius, rng)
        tm.add(
            i,
            T,
            np.array([tree_id]),
            [pts],
            np.array([-1.0]),
            np.array([0.3]),
            np.array([scan_dbh(i)]),
        )
    tm.flush(None)


def test_tree_map_fuses_dbh_over_windows():
    tm = TreeMap(MappingConfig(dbh_window_scans=25))
    rng = np.random.default_rng(1)
    _pass_stem(tm, lambda i: 0.30 + rng.normal(scale=0.01))
    # The window circles alone: two windows, on the 30 cm stem.
    dbh, std, n = tm.window_dbh(7)
    assert n == 2
    assert dbh == pytest.approx(0.30, abs=0.01)
    assert std < 0.01
    # The per-scan DBHs agree: their median decides, its std from their spread and the windows.
    dbh, std, n = tm.dbh(7)
    assert n == 2
    assert dbh == pytest.approx(0.30, abs=0.005)
    assert 0.001 < std < 0.006
    table = tm.table(np.array([7, 8]), np.array([[5.0, 2.0], [1.0, 1.0]]), np.array([5, 1]))
    assert table["id"].tolist() == [7]  # tree 8 has too few observations
    assert table["dbh_m"][0] == pytest.approx(dbh)
    assert table["z"][0] == pytest.approx(0.3)


def test_tree_map_windows_decide_when_scans_disagree():
    """Per-scan DBHs that disagree (the stem merged with a neighbour in every other scan): the
    window circles decide."""
    tm = TreeMap(MappingConfig(dbh_window_scans=25))
    _pass_stem(tm, lambda i: 0.30 if i % 2 else 0.55)
    assert tm.dbh(7)[0] == pytest.approx(tm.window_dbh(7)[0])
    assert tm.dbh(7)[0] == pytest.approx(0.30, abs=0.01)


def test_window_disagreement_widens_the_scan_dbh_std():
    """Per-scan DBHs that agree on 40 cm while the window circles say 30 cm: the median
    decides, and its std carries dbh_disagreement_share of the squared difference."""
    cfg = MappingConfig(dbh_window_scans=25)
    tm = TreeMap(cfg)
    _pass_stem(tm, lambda i: 0.40)
    dbh, std, _ = tm.dbh(7)
    gap = dbh - tm.window_dbh(7)[0]
    assert dbh == pytest.approx(0.40) and gap > 0.08
    assert std == pytest.approx(np.sqrt(cfg.dbh_disagreement_share) * gap, rel=0.05)


def test_scan_dbh_std_counts_views_not_scans():
    """Scans of one view share their error: 8 views of 25 scans each, each view 1 cm off in
    its own way, give the standard error of 8 views, not of 200 scans."""
    cfg = MappingConfig(dbh_window_scans=25)
    offsets = np.array([-1.5, -1.0, -0.5, 0.0, 0.0, 0.5, 1.0, 1.5]) * 0.01
    tm = TreeMap(cfg)
    for i in range(200):
        _scan_dbh_only(tm, i, 3, 0.25 + offsets[i // 25])
    dbh, std, _ = tm.dbh(3)
    assert dbh == pytest.approx(0.25, abs=0.003)
    views = 1.2533 * 1.4826 * np.median(np.abs(offsets)) / np.sqrt(8)
    assert std == pytest.approx(views, rel=0.01)


def test_scan_dbh_buffer_spans_the_whole_observation():
    """More scans than the buffer holds: every other value is dropped and the stride doubled,
    so the kept values span all scans (the first scans are the far approach views)."""
    tm = TreeMap(MappingConfig())
    n = 3 * TreeMap.MAX_SCAN_DBH
    for i in range(n):
        _scan_dbh_only(tm, i, 1, 0.2 if i < n // 2 else 0.3)
    tree = tm.trees[1]
    assert tree.n_scans_dbh == n and len(tree.scan_dbh) < TreeMap.MAX_SCAN_DBH
    kept = np.asarray(tree.scan_dbh)
    assert np.mean(kept == 0.3) == pytest.approx(0.5, abs=0.01)


def test_points_seen_through_a_circle_mark_it_as_no_stem():
    from forestslam.mapping.tree_map import seen_through_share

    rng = np.random.default_rng(2)
    fit = SimpleNamespace(centre=np.array([5.0, 0.0]), radius=0.2)  # a CircleFit's fields
    origins = np.column_stack([np.zeros(200), rng.uniform(-3, 3, 200)])
    # Points on the half each beam meets first (3 cm range noise): a stem hides nothing.
    u = fit.centre - origins
    u /= np.linalg.norm(u, axis=1)[:, None]
    ang = np.arctan2(-u[:, 1], -u[:, 0]) + rng.uniform(-1.2, 1.2, 200)
    near = fit.centre + 0.2 * np.column_stack([np.cos(ang), np.sin(ang)])
    near += u * rng.normal(scale=0.03, size=(200, 1))
    assert seen_through_share(near, origins, fit, 0.03) < 0.05
    # The same points mirrored to the far half (a circle through stems behind each other).
    far = 2 * fit.centre - near
    assert seen_through_share(far, origins, fit, 0.03) > 0.9


BAND_POINT = np.array([[4.0, 0.0, 1.3]])  # one stem return at breast height (base_z 0)


def _scan_dbh_only(tm, scan, tree_id, dbh, band=True):
    """One scan of tree tree_id with perception's DBH dbh and (band) one breast-height return."""
    points = [BAND_POINT if band else np.zeros((0, 3))]
    tm.add(scan, np.eye(4), np.array([tree_id]), points, np.zeros(1), np.ones(1), np.array([dbh]))


def test_tree_map_dbh_from_scans_alone_and_ignores_unmatched():
    tm = TreeMap(MappingConfig())
    for i in range(5):
        tm.add(
            i,
            np.eye(4),
            np.array([-1, 2]),
            [np.zeros((0, 3)), BAND_POINT],
            np.array([0.0, 0.0]),
            np.array([1.0, 1.0]),
            np.array([0.5, 0.2 + 0.01 * (i % 3)]),
        )
    dbh, std, n = tm.dbh(2)
    # The scans agree: their median; std: its standard error (5 scans, fewer than one view).
    assert dbh == pytest.approx(0.21) and n == 0
    assert std == pytest.approx(1.2533 * 1.4826 * 0.01 / np.sqrt(5))
    assert np.isnan(tm.dbh(5)[0])
    # Scans that disagree (a far stem merged with its neighbour in some): no DBH.
    for i in range(5, 10):
        _scan_dbh_only(tm, i, 2, 0.6)
    assert np.isnan(tm.dbh(2)[0])
    # A DBH in only 3 of a tree's 8 scans (the others found no circle): a chance circle.
    for i in range(8):
        _scan_dbh_only(tm, i, 9, 0.3 if i < 3 else np.nan)
    assert np.isnan(tm.dbh(9)[0])


def test_no_dbh_without_stem_points_at_breast_height():
    """Stem-or-not: silhouettes that agree scan after scan (a shrub or foliage looks like a
    1.3 m stem to them) give no DBH unless the tree's band held stem returns in as many scans
    as a window fit needs (dbh_min_window_scans); the tree stays in the table, DBH empty."""
    cfg = MappingConfig()
    tm = TreeMap(cfg)
    for i in range(12):
        _scan_dbh_only(tm, i, 1, 1.30 + 0.01 * (i % 3), band=False)
        _scan_dbh_only(tm, i, 2, 0.20 + 0.01 * (i % 3), band=i < cfg.dbh_min_window_scans - 1)
        _scan_dbh_only(tm, i, 3, 0.20 + 0.01 * (i % 3), band=i < cfg.dbh_min_window_scans)
    assert not tm.is_stem(tm.trees[1]) and np.isnan(tm.dbh(1)[0])
    assert not tm.is_stem(tm.trees[2]) and np.isnan(tm.dbh(2)[0])
    assert tm.is_stem(tm.trees[3]) and tm.dbh(3)[0] == pytest.approx(0.21)
    # A window circle on a tree perception measured in only 5 of its 12 scans: chance.
    for i in range(12):
        _scan_dbh_only(tm, i, 4, 0.13 if i < 5 else np.nan)
    tm.trees[4].measurements = [(0.13, 40.0)]
    assert not tm.is_stem(tm.trees[4]) and np.isnan(tm.dbh(4)[0])
    table = tm.table(np.array([1, 2, 3]), np.zeros((3, 2)), np.full(3, 12))
    assert table["id"].tolist() == [1, 2, 3]  # positions kept for the localizer
    assert np.isnan(table["dbh_m"][:2]).all() and np.isfinite(table["dbh_m"][2])


def test_tree_map_drops_windows_that_disagree_with_the_scans_width():
    """A window circle 3x the stem's per-scan (silhouette) DBH is a circle through a clump: it
    is not fused into the window DBH; the per-scan DBHs, which agree, decide anyway."""
    tm = TreeMap(MappingConfig())
    for i in range(10):
        _scan_dbh_only(tm, i, 1, 0.18 + 0.002 * (i % 3))
    # Two clump windows outvote the stem's one in the median: the scans' width gates them.
    tm.trees[1].measurements = [(0.55, 80.0), (0.56, 80.0), (0.19, 40.0)]
    dbh, _, n = tm.window_dbh(1)
    assert n == 1 and dbh == pytest.approx(0.19)
    assert tm.dbh(1)[0] == pytest.approx(0.182)
    tm.trees[1].measurements = [(0.55, 80.0)]
    assert np.isnan(tm.window_dbh(1)[0])
    dbh, _, n = tm.dbh(1)
    assert n == 0 and dbh == pytest.approx(0.182)
    # Windows narrower than the scans' width are kept: scans that merged the stem with a
    # neighbour widen it, the windows' circle does not follow them.
    tm.trees[1].measurements = [(0.09, 40.0), (0.095, 40.0)]
    dbh, _, n = tm.window_dbh(1)
    assert n == 2 and dbh == pytest.approx(0.0925)


def test_window_blocks_are_aligned_across_their_beams_against_pose_drift():
    # Poses drifting sideways by up to 7 cm over each 25-scan window (opposite ways in the two
    # windows) smear the arcs: each window's circle is off by 1.5-3 cm without the alignment.
    errors = {}
    for iterations in (0, 2):
        rng = np.random.default_rng(0)
        tm = TreeMap(MappingConfig(dbh_align_iterations=iterations, dbh_align_block_scans=5))
        centre, radius = np.array([5.0, 2.0]), 0.15
        for i in range(50):
            sensor = np.array([0.1 * i, 0.0])
            pts = stem_scan(sensor, centre, radius, rng)
            T = np.eye(4)
            T[:2, 3] = sensor + [0.0, 0.003 * (i % 25) * (1 if i >= 25 else -1)]
            tm.add(i, T, np.array([7]), [pts], np.array([-1.0]), np.array([0.3]), np.array([0.3]))
        tm.flush(None)
        errors[iterations] = np.abs([d - 0.30 for d, _ in tm.trees[7].measurements])
    assert len(errors[0]) == len(errors[2]) == 2
    assert errors[0].max() > 0.025
    assert errors[2].max() < 0.02
    assert errors[2].mean() < 0.6 * errors[0].mean()
