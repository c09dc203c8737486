"""Global localization by Delaunay triangle stars: known poses, order, rejection, map files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.localization import (
    LocalizationConfig,
    TreeMap,
    aggregate_stems,
    build_map,
    extract_trunks,
    load_map,
    localize,
)

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def stand(n: int, extent: float, seed: int, spacing: float = 2.0) -> np.ndarray:
    """Random trunk positions with a minimum spacing (thinned Poisson)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, extent, (int(n * 1.6), 2))
    pairs = cKDTree(xy).query_pairs(spacing, output_type="ndarray")
    keep = np.ones(len(xy), bool)
    keep[pairs[:, 1]] = False
    return xy[keep][:n]


def observe(map_xy, pose, radius, noise, miss, outliers, seed):
    """Trunks within radius of pose (x, y, yaw) in the local frame, with noise, misses, fakes."""
    rng = np.random.default_rng(seed)
    d = map_xy - np.asarray(pose[:2])
    keep = (np.hypot(d[:, 0], d[:, 1]) <= radius) & (rng.uniform(size=len(d)) >= miss)
    d = d[keep]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    local += rng.normal(0, noise, local.shape)
    r = radius * np.sqrt(rng.uniform(size=outliers))
    a = rng.uniform(-np.pi, np.pi, outliers)
    return np.vstack([local, np.column_stack([r * np.cos(a), r * np.sin(a)])])


def yaw_error(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


@pytest.fixture(scope="module")
def forest():
    xy = stand(800, 200.0, seed=1)
    return xy, build_map(xy)


def test_recovers_known_rigid_transform_with_noise_outliers_and_missing(forest):
    xy, tree_map = forest
    rng = np.random.default_rng(3)
    accepted = 0
    for q in range(15):
        truth = (*rng.uniform(40, 160, 2), rng.uniform(-math.pi, math.pi))
        local = observe(xy, truth, 20.0, noise=0.05, miss=0.2, outliers=4, seed=10 + q)
        loc = localize(tree_map, local)
        if loc.rejected:
            continue
        accepted += 1
        assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.1
        assert yaw_error(loc.yaw, truth[2]) < math.radians(0.5)
        assert loc.inliers >= 8
        assert loc.covariance.shape == (3, 3)
        assert np.all(np.linalg.eigvalsh(loc.covariance) > 0)
        # The covariance is of the right size for 5 cm trunk noise.
        assert 0.005 < math.sqrt(loc.covariance[0, 0]) < 0.1
    assert accepted >= 14


def test_exact_without_noise(forest):
    xy, tree_map = forest
    truth = (90.0, 110.0, -2.0)
    local = observe(xy, truth, 25.0, noise=0.0, miss=0.0, outliers=0, seed=0)
    loc = localize(tree_map, local)
    assert loc.accepted
    assert loc.x == pytest.approx(truth[0], abs=1e-8)
    assert loc.y == pytest.approx(truth[1], abs=1e-8)
    assert yaw_error(loc.yaw, truth[2]) < 1e-10
    assert loc.inliers == len(local)
    # Matches pair every local trunk with the map trunk it came from.
    T = loc.matrix()
    mapped = np.column_stack([local, np.zeros(len(local)), np.ones(len(local))]) @ T.T
    np.testing.assert_allclose(mapped[loc.matches[:, 0], :2], xy[loc.matches[:, 1]], atol=1e-8)


def test_invariant_to_trunk_order(forest):
    xy, tree_map = forest
    local = observe(xy, (70.0, 60.0, 0.9), 20.0, noise=0.05, miss=0.15, outliers=3, seed=5)
    perm = np.random.default_rng(9).permutation(len(local))
    a, b = localize(tree_map, local), localize(tree_map, local[perm])
    assert a.accepted and b.accepted
    assert (a.x, a.y, a.yaw, a.inliers) == pytest.approx((b.x, b.y, b.yaw, b.inliers), abs=1e-9)


def test_rejects_a_place_not_in_the_map(forest):
    _, tree_map = forest
    other = stand(800, 200.0, seed=99)
    for q in range(10):
        pose = (40.0 + 12 * q, 100.0, 0.5 * q)
        local = observe(other, pose, 20.0, noise=0.05, miss=0.1, outliers=2, seed=q)
        assert localize(tree_map, local).rejected


@pytest.mark.parametrize(
    "local",
    [
        np.zeros((0, 2)),
        np.array([[1.0, 2.0]]),
        np.array([[0.0, 0.0], [5.0, 1.0]]),
        np.column_stack([np.arange(10.0), 2 * np.arange(10.0)]),  # collinear
        np.array([[1.0, 1.0]] * 5 + [[4.0, 2.0]] * 3),  # duplicates: 2 distinct trunks
        np.full((6, 2), np.nan),
    ],
)
def test_degenerate_queries_are_rejected_not_raised(forest, local):
    loc = localize(forest[1], local)
    assert loc.rejected
    assert loc.reason


def test_bad_shape_is_an_input_error(forest):
    with pytest.raises(InputError):
        localize(forest[1], np.zeros((5, 3)))


def test_map_save_load_round_trip(forest, tmp_path):
    xy, _ = forest
    dbh = np.linspace(0.1, 0.5, len(xy))
    tree_map = TreeMap(xy, dbh, ids=np.arange(len(xy)) + 100)
    path = tree_map.save(tmp_path / "stand")
    assert path.suffix == ".npz"
    loaded = load_map(path)
    np.testing.assert_array_equal(loaded.xy, tree_map.xy)
    np.testing.assert_array_equal(loaded.dbh_m, dbh)
    np.testing.assert_array_equal(loaded.ids, np.arange(len(xy)) + 100)
    np.testing.assert_array_equal(loaded.triangles, tree_map.triangles)
    with np.load(path) as data:
        assert str(data["format"]) == "forestslam-tree-map"
        assert data["star_features"].shape == (tree_map.n_stars, 8)
        assert data["triangles"].shape == (len(tree_map.triangles), 3)
    local = observe(xy, (100.0, 100.0, 1.0), 20.0, 0.03, 0.1, 2, seed=4)
    a, b = localize(tree_map, local), localize(loaded, local)
    assert (a.x, a.y, a.yaw) == (b.x, b.y, b.yaw)


def test_map_from_tree_csv_with_extra_columns(tmp_path):
    xy = stand(300, 120.0, seed=6)
    csv = tmp_path / "inventory.csv"
    lines = ["plot,tree,x,y,dbh_cm,height_m"]
    lines += [f"3,{i + 1},{x:.4f},{y:.4f},{25 + i % 10},18.5" for i, (x, y) in enumerate(xy)]
    csv.write_text("\n".join(lines) + "\n")
    tree_map = load_map(csv)
    assert len(tree_map) == 300
    np.testing.assert_allclose(tree_map.xy, xy, atol=1e-4)
    assert tree_map.dbh_m[0] == pytest.approx(0.25)
    assert tree_map.ids[0] == 1
    loc = localize(tree_map, observe(xy, (60.0, 60.0, -0.4), 20.0, 0.03, 0.1, 1, seed=2))
    assert loc.accepted and math.hypot(loc.x - 60, loc.y - 60) < 0.1


def test_bad_map_files(tmp_path):
    with pytest.raises(InputError):
        load_map(tmp_path / "missing.npz")
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="x and y"):
        load_map(bad)
    other = tmp_path / "other.npz"
    np.savez(other, foo=np.zeros(3))
    with pytest.raises(InputError, match="not a forestslam tree map"):
        load_map(other)
    with pytest.raises(InputError):
        build_map(np.zeros((4, 3)))


def test_aggregate_stems_moves_frames_into_the_last_and_merges():
    world = np.array([[5.0, 0.0], [0.0, 6.0], [-4.0, -3.0]])
    poses, xys = [], []
    for k in range(4):
        yaw, pos = 0.3 * k, np.array([1.0 * k, 0.5 * k])
        T = np.eye(4)
        T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        T[:2, 3] = pos
        poses.append(T)
        xys.append((world - pos) @ T[:2, :2])  # world -> sensor k
    merged = aggregate_stems(xys, poses, LocalizationConfig())
    expected = (world - poses[-1][:2, 3]) @ poses[-1][:2, :2]
    assert len(merged) == 3
    for p in expected:
        assert np.min(np.hypot(*(merged - p).T)) < 1e-9
    # A detection in only one of >= 3 frames is dropped when two observations are required.
    xys[0] = np.vstack([xys[0], [[10.0, 10.0]]])
    assert len(aggregate_stems(xys, poses, LocalizationConfig(min_observations=2))) == 3
    merged, seen = aggregate_stems(xys, poses, LocalizationConfig(), return_observations=True)
    assert len(merged) == 4 and sorted(seen.tolist()) == [1, 4, 4, 4]


def _cluttered_drive(xy, rng, frames=5, transient=6, radius=20.0):
    """Frames 3 m apart on a straight path ending 2-8 m from a random tree, 1.5 m off every
    trunk: true trunks within radius (15 % missed, 5 cm noise) plus `transient` false
    detections per frame that do not repeat (clutter). Returns the frames' trunks, their poses
    T_world_sensor and the last frame's true (x, y)."""
    from scipy.spatial import cKDTree

    tree, lo, hi = cKDTree(xy), xy.min(axis=0) + 30, xy.max(axis=0) - 30
    while True:
        a, heading = rng.uniform(-math.pi, math.pi, 2)
        end = xy[rng.integers(len(xy))] + rng.uniform(2, 8) * np.array([math.cos(a), math.sin(a)])
        path = end + np.outer(
            3.0 * np.arange(1 - frames, 1), [math.cos(heading), math.sin(heading)]
        )
        if (tree.query(path)[0] > 1.5).all() and (path > lo).all() and (path < hi).all():
            break
    c, s = math.cos(heading), math.sin(heading)
    xys, poses = [], []
    for pos in path:
        d = xy - pos
        d = d[(np.hypot(*d.T) < radius) & (rng.uniform(size=len(d)) > 0.15)]
        local = d @ np.array([[c, -s], [s, c]]) + rng.normal(0, 0.05, d.shape)
        r, b = (
            radius * np.sqrt(rng.uniform(size=transient)),
            rng.uniform(-math.pi, math.pi, transient),
        )
        xys.append(np.vstack([local, np.column_stack([r * np.cos(b), r * np.sin(b)])]))
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = pos
        poses.append(T)
    return xys, poses, end


def test_aggregated_views_gathering_transient_clutter_are_found():
    """5 frames hold more trunks than their last frame alone and must not be found less often.
    Each frame adds its own transient false detections while the true trunks saturate; the
    single-triangle stage tries triangles of trunks seen in >= 2 frames first (main spent its
    budget on triangles holding clutter: 32/40 found here, and 97.2 % against 99.7 % for 1 frame
    on the bench's clustered stand), and the inlier fraction counts those trunks only."""
    from forestslam.sim.stand import load_stand

    xy = load_stand(
        "generated",
        seed=16,
        size_m=(500.0, 250.0),
        process="clustered",
        density_per_ha=72.08,
        cluster_radius_m=30.0,
        trees_per_cluster=70.0,
        min_spacing_m=1.0,
    ).xy
    tree_map = build_map(xy)
    rng = np.random.default_rng(5)
    found = {"5 frames": 0, "last frame": 0}
    wrong = 0
    for _ in range(40):
        xys, poses, end = _cluttered_drive(xy, rng)
        local, seen = aggregate_stems(xys, poses, return_observations=True)
        views = {"5 frames": (local, seen), "last frame": (xys[-1], None)}
        for name, (trunks, counts) in views.items():
            loc = localize(tree_map, trunks, observations=counts)
            right = math.hypot(loc.x - end[0], loc.y - end[1]) < 0.5
            found[name] += loc.accepted and right
            wrong += loc.accepted and not right
    assert wrong == 0
    assert found["5 frames"] >= 38
    assert found["5 frames"] >= found["last frame"]
    with pytest.raises(InputError, match="observations"):
        localize(tree_map, local, observations=seen[:-1])


def test_extract_trunks_from_a_cloud():
    rng = np.random.default_rng(0)
    g = np.mgrid[0:20:0.25, 0:20:0.25].reshape(2, -1).T
    ground = np.column_stack([g, 0.02 * rng.uniform(size=len(g))])
    centres = np.array([[4.0, 5.0], [12.0, 15.0], [16.0, 4.0]])
    a = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    z = np.arange(0, 3.0, 0.05)
    stems = [
        np.column_stack(
            [
                np.repeat(c[0] + 0.2 * np.cos(a)[None], len(z), 0).ravel(),
                np.repeat(c[1] + 0.2 * np.sin(a)[None], len(z), 0).ravel(),
                np.repeat(z, len(a)),
            ]
        )
        for c in centres
    ]
    found = extract_trunks(np.vstack([ground, *stems]))
    assert len(found) == 3
    for c in centres:
        assert np.min(np.hypot(*(found - c).T)) < 0.05


def test_map_from_a_point_cloud_file(tmp_path):
    from forestslam.io import write_cloud

    rng = np.random.default_rng(1)
    g = np.mgrid[0:30:0.3, 0:30:0.3].reshape(2, -1).T
    parts = [np.column_stack([g, 0.02 * rng.uniform(size=len(g))])]
    centres = stand(12, 26.0, seed=8, spacing=4.0) + 2.0
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    for c in centres:
        for z in np.arange(0, 3.5, 0.05):
            parts.append(
                np.column_stack([c[0] + 0.15 * np.cos(a), c[1] + 0.15 * np.sin(a), z + 0 * a])
            )
    path = tmp_path / "map.ply"
    write_cloud(path, np.vstack(parts))
    tree_map = load_map(path)
    assert len(tree_map) == len(centres)
    d = np.hypot(*(tree_map.xy[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    assert d.min(axis=1).max() < 0.05


@pytest.mark.skipif(not (DATA / "fortls").is_dir(), reason="../shared/data/fortls absent")
def test_real_fortls_plot_found_among_all_plots():
    from forestslam.io import read_trees_csv

    field = read_trees_csv(DATA / "fortls" / "field_trees.csv")
    tls = read_trees_csv(DATA / "fortls" / "tls_trees.csv")
    plots = sorted(set(field["plot"].astype(int)))
    offsets = {p: np.array([100.0 * k, 0.0]) for k, p in enumerate(plots)}
    fxy = np.column_stack([field["x"], field["y"]])
    tree_map = build_map(np.vstack([fxy[field["plot"] == p] + offsets[p] for p in plots]))
    txy = np.column_stack([tls["x"], tls["y"]])
    for p in plots[:4]:
        loc = localize(tree_map, txy[tls["plot"] == p])
        assert loc.accepted
        off = np.array([loc.x, loc.y]) - offsets[p]
        # The documented frame difference: about -9 deg and up to 2.5 m.
        assert np.hypot(*off) < 3.0
        assert -12.0 < math.degrees(loc.yaw) < -6.0
