"""MLS-to-TLS registration on a synthetic plot with known poses."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from tls_world import mls_frame, pose, reference_cloud, stand

from forestslam.errors import InputError
from forestslam.tls import TlsConfig, coarse_stem_alignment, register_mls_to_tls
from forestslam.tls.config import RegistrationConfig
from forestslam.tls.runner import parse_initial_pose, write_products


def _rot_err_deg(a: np.ndarray, b: np.ndarray) -> float:
    d = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))


@pytest.fixture(scope="module")
def world():
    trees = stand()
    truth = [pose(1.0 + 0.4 * k, -0.5 + 0.1 * k, 0.3 + 0.02 * k) for k in range(4)]
    frames = [mls_frame(trees, T, 0.1 * k, seed=k) for k, T in enumerate(truth)]
    return trees, reference_cloud(trees), truth, frames


@pytest.fixture(scope="module")
def run(world):
    _, ref, _, frames = world
    return register_mls_to_tls(frames, ref, TlsConfig())


def test_poses_recovered_without_initial_guess(world, run):
    _, _, truth, _ = world
    assert run.initial_method == "stems"
    assert len(run.frames) == len(truth)
    for rec, T in zip(run.frames, truth, strict=True):
        assert np.linalg.norm(rec.T_tls_sensor[:3, 3] - T[:3, 3]) < 0.01
        assert _rot_err_deg(rec.T_tls_sensor, T) < 0.1
        assert rec.converged and not rec.degenerate
    # The walk is placed once init.min_frames frames are accumulated; the frames before get
    # their pose chained back from it but never join the map; all later frames join it.
    n_before = TlsConfig().init.min_frames - 1
    assert all(r.reason.startswith("before the walk was placed") for r in run.frames[:n_before])
    assert all(r.accepted and not r.reason for r in run.frames[n_before:])
    assert len(run.map_points) > len(run.reference) // 4  # voxelized but not lost
    # Each map point carries how many merges fell in its voxel: frames add to the reference's.
    assert run.map_counts.shape == (len(run.map_points),)
    assert run.map_counts.min() >= 1 and run.map_counts.max() > 1


def test_products_and_coverage(world, run, tmp_path):
    trees, _, _, _ = world
    summary = write_products(run, tmp_path, TlsConfig())
    for name in ("trajectory.tum", "plot.laz", "trees.csv", "coverage.json", "plot.png"):
        assert (tmp_path / name).stat().st_size > 0
    lines = (tmp_path / "trees.csv").read_text().splitlines()
    assert lines[0] == "id,x,y,z,dbh_m,dbh_std_m,position_measured,observations"
    rows = np.array([[float(v or "nan") for v in ln.split(",")] for ln in lines[1:]])
    # Every mapped stem is a true stem with its DBH within 1.5 cm.
    assert len(rows) >= 10
    for row in rows:
        d = np.linalg.norm(trees[:, :2] - row[1:3], axis=1)
        k = int(np.argmin(d))
        assert d[k] < 0.02
        assert abs(row[4] - trees[k, 2]) < 0.015
    cov = json.loads((tmp_path / "coverage.json").read_text())
    assert cov["mean_merged"] > cov["mean_tls"]
    assert cov["mean_tls"] <= 0.6  # a single station sees about half of each stem
    assert summary["frames"] == 4
    # The reference is one scan in its station's frame: the face test takes the origin (run.yaml).
    assert summary["reference_scanners"]["xy"] == [[0.0, 0.0]]
    # Every frame that did not join the map is listed with its reason.
    rows = (tmp_path / "unmerged.csv").read_text().splitlines()
    assert rows[0] == "stamp,has_pose,reason"
    assert len(rows) - 1 == sum(not r.accepted for r in run.frames) >= 1
    assert all(",1," in row and row.endswith('"') for row in rows[1:])
    assert sum(summary["unmerged"].values()) == len(rows) - 1


def test_initial_pose_option_and_parse():
    T = parse_initial_pose("1.0,-0.5,17.2")
    assert np.allclose(T[:3, 3], [1.0, -0.5, 0.0])
    assert np.isclose(np.degrees(np.arctan2(T[1, 0], T[0, 0])), 17.2)
    with pytest.raises(InputError):
        parse_initial_pose("1,2")
    with pytest.raises(InputError):
        parse_initial_pose("a,b,c")


def test_empty_reference_is_a_clear_error(world):
    _, _, _, frames = world
    with pytest.raises(InputError, match="reference"):
        register_mls_to_tls(frames[:1], np.zeros((0, 3)))
    with pytest.raises(InputError, match="reference"):
        register_mls_to_tls(frames[:1], np.full((5000, 3), np.nan))


def test_coarse_stem_alignment_recovers_planar_pose():
    rng = np.random.default_rng(4)
    dst = rng.uniform(-15, 15, (40, 2))
    r = rng.uniform(0.08, 0.25, 40)
    x, y, yaw = 3.0, -2.0, 1.1
    c, s = np.cos(yaw), np.sin(yaw)
    pick = np.argsort(np.linalg.norm(dst - [x, y], axis=1))[:8]
    # Source = the 8 stems nearest the sensor, in its frame, with 2 cm noise and one extra.
    src = (dst[pick] - [x, y]) @ np.array([[c, -s], [s, c]])
    src = np.vstack([src + rng.normal(0, 0.02, src.shape), [[1.0, 1.0]]])
    src_r = np.append(r[pick], 0.1)
    found = coarse_stem_alignment(src, src_r, dst, r, RegistrationConfig())
    assert found is not None
    (fx, fy, fyaw), n_in = found
    assert n_in >= 7
    assert abs(fx - x) < 0.05 and abs(fy - y) < 0.05 and abs(fyaw - yaw) < np.radians(0.5)
    assert coarse_stem_alignment(src[:1], src_r[:1], dst, r, RegistrationConfig()) is None


def test_local_target_is_cropped_and_recropped_only_after_moving(world):
    from forestslam.tls.pipeline import _GlobalMap

    _, ref, _, _ = world
    cfg = TlsConfig()
    cfg.map.target_radius_m = 5.0
    cfg.map.target_recrop_m = 2.0
    gmap = _GlobalMap(ref, cfg)
    t1, built = gmap.target_at(np.array([0.0, 0.0]), (-1.5, 1.0))
    assert built and 0 < len(t1) < len(gmap.points)
    # Cropped in height too: only the frame's band plus the margin.
    band = gmap.reference_target[:, 2] <= 1.0 + cfg.map.target_z_margin_m
    assert len(t1) <= np.count_nonzero(band)
    t2, built = gmap.target_at(np.array([1.5, 0.0]), (-1.4, 0.9))
    assert not built and t2 is t1
    _, built = gmap.target_at(np.array([1.5, 0.0]), (-1.4, 1.0 + cfg.map.target_z_margin_m + 0.1))
    assert built
    _, built = gmap.target_at(np.array([4.0, 0.0]), (-1.4, 0.9))
    assert built


def test_lm_target_holds_the_reference_and_only_confirmed_merged_voxels_away_from_it():
    from forestslam.tls.pipeline import _GlobalMap

    rng = np.random.default_rng(8)
    wall = np.column_stack([rng.uniform(0, 4, 20000), np.zeros(20000), rng.uniform(0, 2, 20000)])
    cfg = TlsConfig()
    cfg.map.rebuild_every_frames = 1
    cfg.map.lm_target = "confirmed"
    gmap = _GlobalMap(wall, cfg)
    n_ref = len(gmap.reference_target)
    thick = wall + [0.0, 0.06, 0.0]  # the same wall seen 6 cm off: a wall a voxel thicker
    back = wall + [0.0, 0.5, 0.0]  # a surface the reference did not see
    stray = np.column_stack([rng.uniform(0, 4, 500), np.full(500, -1.0), rng.uniform(0, 2, 500)])
    gmap.add(np.vstack([thick, back, stray]))
    target, _ = gmap.target_at(np.array([2.0, 0.0]), (0.0, 2.0))
    assert len(target) == n_ref  # one merge batch confirms nothing
    gmap.add(np.vstack([thick, back]))
    gmap.target_at(np.array([2.0, 0.0]), (0.0, 2.0))
    y = gmap.target_points[:, 1]
    assert np.count_nonzero(np.abs(y) < 0.2) == n_ref  # the wall stays the reference's
    assert np.count_nonzero(np.abs(y - 0.5) < 0.1) > 0.5 * n_ref  # the new surface joins
    assert not np.any(y < -0.5)  # the stray voxels, seen once, do not
    assert len(gmap.points) > n_ref  # the map itself keeps every merged point
    cfg.map.lm_target = "map"  # the whole map: every merged voxel from the first batch on
    whole = _GlobalMap(wall, cfg)
    whole.add(np.vstack([thick, back, stray]))
    whole.target_at(np.array([2.0, 0.0]), (0.0, 2.0))
    y = whole.target_points[:, 1]
    assert np.any(y < -0.5) and np.count_nonzero(np.abs(y) < 0.2) > n_ref


def test_large_correction_from_the_prediction_is_not_trusted():
    from forestslam.tls.pipeline import _trusted

    cfg = TlsConfig()
    fields = {  # the fields of a StemCentreLmResult _trusted reads
        "converged": True,
        "degenerate": False,
        "real_inliers": 50,
        "real_rms_m": 0.02,
        "T_target_source": pose(0.5, 0.0, 0.0),
    }
    lm = SimpleNamespace(**fields)
    assert _trusted(lm, pose(0.0, 0.0, 0.0), cfg)
    lm = SimpleNamespace(**{**fields, "T_target_source": pose(3.0, 0.0, 0.0)})
    assert not _trusted(lm, pose(0.0, 0.0, 0.0), cfg)
    assert not _trusted(SimpleNamespace(**{**fields, "converged": False}), None, cfg)
    assert not _trusted(SimpleNamespace(**{**fields, "real_rms_m": 0.5}), None, cfg)


def test_velocity_prediction_mode_recovers_poses(world):
    _, ref, truth, frames = world
    cfg = TlsConfig()
    cfg.registration.initial_pose = "velocity"
    out = register_mls_to_tls(frames, ref, cfg)
    assert len(out.frames) == len(truth)
    for rec, T in zip(out.frames, truth, strict=True):
        assert np.linalg.norm(rec.T_tls_sensor[:3, 3] - T[:3, 3]) < 0.01
        assert _rot_err_deg(rec.T_tls_sensor, T) < 0.1


def _skewed(scan, twist: np.ndarray, sweep_s: float = 0.1):
    """The scan as a spinning sensor moving with the body twist (6,) per second would measure
    it: each point in the sensor frame at its own time (azimuth sweep from the stamp)."""
    from forestslam.io import Scan
    from forestslam.odometry.deskew import se3_exp

    p = scan.points
    t = (np.arctan2(p[:, 1], p[:, 0]) + np.pi) / (2 * np.pi) * sweep_s
    t = np.round(t / 1e-3) * 1e-3  # firing groups of 1 ms
    out = np.empty_like(p)
    for tk in np.unique(t):
        m = t == tk
        T_inv = np.linalg.inv(se3_exp(twist * tk))
        out[m] = p[m] @ T_inv[:3, :3].T + T_inv[:3, 3]
    return Scan(scan.stamp, out, scan.intensity, scan.ring, t)


def test_moving_spinning_frames_are_deskewed(world):
    """A walk at 0.8 m/s turning 6 deg/s: skewed frames with per-point time; the poses at the
    stamps are recovered within 1.5 cm with the deskew, markedly worse without."""
    from forestslam.odometry.deskew import se3_exp

    trees, ref, _, _ = world
    twist = np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.1])
    T0 = pose(1.0, -0.5, 0.3)
    truth = [T0 @ se3_exp(twist * 0.1 * k) for k in range(6)]
    frames = [
        _skewed(mls_frame(trees, T, 0.1 * k, seed=10 + k), twist) for k, T in enumerate(truth)
    ]

    def errors(deskew: bool) -> np.ndarray:
        cfg = TlsConfig()
        cfg.registration.deskew = deskew
        run = register_mls_to_tls(frames, ref, cfg)
        assert len(run.frames) == len(truth)
        return np.array(
            [
                np.linalg.norm(r.T_tls_sensor[:3, 3] - T[:3, 3])
                for r, T in zip(run.frames, truth, strict=True)
            ]
        )

    on, off = errors(True), errors(False)
    # The velocity is known from the second frame on (from still skewed frames at first).
    assert on[2] < 0.015 and np.all(on[3:] < 0.005), on
    assert np.mean(off[2:]) > 2 * np.mean(on[2:]), (on, off)


def test_only_points_within_the_merge_range_join_the_map(world, run):
    """An angular pose error moves a point by its range times the error, so only a frame's
    near points join the map (MapConfig.merge_max_range_m); the frame registers on all."""
    _, ref, truth, frames = world
    cfg = TlsConfig()
    cfg.map.merge_max_range_m = 5.0
    near = register_mls_to_tls(frames, ref, cfg)
    for a, b in zip(near.frames, run.frames, strict=True):  # registration unchanged
        assert np.allclose(a.T_tls_sensor, b.T_tls_sensor, atol=1e-9)
    voxel = cfg.map.voxel_m
    keys_near = {tuple(k) for k in np.floor(near.map_points / voxel).astype(np.int64)}
    keys_all = np.floor(run.map_points / voxel).astype(np.int64)
    only_far = np.array([k not in keys_near for k in map(tuple, keys_all)])
    sensors = np.array([r.T_tls_mid[:3, 3] for r in run.frames if r.accepted])
    dist = np.linalg.norm(run.map_points[only_far, None, :] - sensors[None], axis=2).min(axis=1)
    assert only_far.sum() > 100  # the default range merges farther points
    # Voxels are means of what was merged into them (measured: nearest 4.90 m): none well
    # inside the range, most well beyond it.
    assert dist.min() > 5.0 - 0.15
    assert np.median(dist) > 6.0
    assert len(near.map_points) < len(run.map_points)


def test_voxel_map_merges_only_points_in_new_voxels():
    from forestslam import _core
    from forestslam.tls.pipeline import _VoxelCloud

    rng = np.random.default_rng(2)
    base = rng.uniform(0, 1, (5000, 3))
    cloud = _VoxelCloud(base, 0.1, _core)
    n0 = len(cloud.points)
    assert n0 == len(_core.voxel_downsample(base, 0.1))
    cloud.merge(base + rng.normal(0, 0.001, base.shape))  # same voxels (mostly): ~nothing new
    assert len(cloud.points) - n0 < 0.1 * n0
    cloud.merge(base + [5.0, 0.0, 0.0])  # all new voxels: all kept
    assert len(cloud.points) >= 2 * n0 - 0.1 * n0
    cloud.merge(base + [5.0, 0.0, 0.0])  # merged again: nothing new
    n1 = len(cloud.points)
    cloud.merge(base + [5.0, 0.0, 0.0])
    assert len(cloud.points) == n1
    # One point per voxel.
    keys = np.floor(cloud.points / 0.1).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(keys)


def test_voxel_map_side_store_gives_the_same_map_as_merging_into_the_map_at_once():
    from forestslam import _core
    from forestslam.tls.pipeline import _VoxelCloud

    rng = np.random.default_rng(5)
    base = rng.uniform(0, 4, (20000, 3))
    batched, direct = _VoxelCloud(base, 0.1, _core), _VoxelCloud(base, 0.1, _core)
    direct.SIDE_FRACTION = 0.0  # every new voxel straight into the map (the old way)
    side_used = consolidated = False
    for k in range(6):  # half in known voxels, half in new ones, some seen again later
        batch = np.vstack([rng.uniform(0, 4, (3000, 3)), rng.uniform(4, 5 + k, (3000, 3))])
        side_before = len(batched._side[0])
        batched.merge(batch)
        direct.merge(batch)
        assert len(batched) == len(direct)
        side_used |= len(batched._side[0]) > 0
        consolidated |= side_before > 0 and len(batched._side[0]) == 0
    assert side_used and consolidated  # both paths were taken
    np.testing.assert_array_equal(batched.points, direct.points)
    np.testing.assert_array_equal(batched._main[2], direct._main[2])
    # A voxel seen by three merges holds the mean of the three merges' centroids.
    cloud = _VoxelCloud(np.array([[10.01, 10.01, 10.01]]), 0.1, _core)
    for p in ([10.03, 10.01, 10.01], [10.05, 10.01, 10.01]):
        cloud.merge(np.vstack([np.array([p]), rng.uniform(0, 1, (50, 3))]))
    at = np.flatnonzero(np.all(np.abs(cloud.points - 10.0) < 0.1, axis=1))
    np.testing.assert_allclose(cloud.points[at], [[10.03, 10.01, 10.01]], atol=1e-12)
    # ... and counts them: three merges, while voxels seen once count 1 (aligned with points).
    assert len(cloud.counts) == len(cloud.points)
    assert cloud.counts[at].tolist() == [3.0]
    assert np.all(cloud.counts >= 1)
    np.testing.assert_array_equal(batched.counts, direct.counts)


def test_a_frame_whose_rigid_lm_runs_out_in_a_sharp_turn_is_registered_with_its_sweep(world):
    """A frame turning 86 deg/s within its own sweep (a jolt the constant velocity of the
    frames before it does not know) is distorted, so the rigid LM creeps towards its minimum
    for many rounds; given too few (5 here; longleaf-lawn-20m-b frames 98-104 ran out of
    15 on vibration), it is not trusted, and before the walk lost three frames and was
    relocalized. Registered again with its motion during the sweep from where the rigid LM
    stopped, the frame converges where the full budget takes it, is verified like any other
    frame and joins the map."""
    from forestslam.odometry.deskew import se3_exp

    trees, ref, _, _ = world
    walk, turn = np.array([0.8, 0, 0, 0, 0, 0.0]), np.array([0.8, 0, 0, 0, 0, 1.5])
    frames, T = [], pose(-1.0, -0.5, 0.3)
    for k in range(8):
        twist = turn if k == 4 else walk
        frames.append(_skewed(mls_frame(trees, T, 0.1 * k, seed=30 + k), twist))
        T = T @ se3_exp(twist * 0.1)

    def run(rounds: int):
        cfg = TlsConfig()
        cfg.registration.lm_max_rounds = rounds
        cfg.registration.rescue_in_sweep = True
        return register_mls_to_tls(frames, ref, cfg, initial_pose=pose(-1.0, -0.5, 0.3))

    short, full = run(5), run(15)
    assert not any(r.relocalized for r in short.frames)
    assert all(r.accepted for r in short.frames[3:]), [r.reason for r in short.frames]
    assert len(short.frames[4].sweep)
    gaps = [
        np.linalg.norm(a.T_tls_mid[:3, 3] - b.T_tls_mid[:3, 3])
        for a, b in zip(short.frames, full.frames, strict=True)
    ]
    assert all(g < 0.01 for g in gaps), gaps


def test_voxel_map_selection_without_consolidating_equals_selecting_the_map():
    # The LM target is cropped from the map while new voxels wait in the side store: the crop
    # (main's and side's selections merged in key order) must equal cropping the whole map.
    from forestslam import _core
    from forestslam.tls.pipeline import _VoxelCloud

    rng = np.random.default_rng(9)
    cloud = _VoxelCloud(rng.uniform(0, 4, (20000, 3)), 0.1, _core)
    cloud.merge(np.vstack([rng.uniform(0, 4, (2000, 3)), rng.uniform(4, 5, (2000, 3))]))
    assert len(cloud._side[0]) > 0  # new voxels wait beside the map

    def select(p):
        return (p[:, 2] > 1.0) & (np.hypot(p[:, 0] - 3.5, p[:, 1] - 2.0) < 1.5)

    selected = cloud.points_where(select)
    assert len(cloud._side[0]) > 0  # not consolidated by the selection
    everything = cloud.points  # consolidates
    np.testing.assert_array_equal(selected, everything[select(everything)])
    assert 0 < len(selected) < len(everything)
