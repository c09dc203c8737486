"""The registered cloud map: keyframes placed by their optimised poses, voxels labelled."""

from __future__ import annotations

import numpy as np

from forestslam.mapping.cloud_map import CloudMap, label_stems


def _pose(x, yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3] = x
    return T


def test_keyframes_are_placed_by_the_poses_given_at_build_and_labelled():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-5, 5, (500, 2)), np.full(500, -1.5)])
    stem = np.column_stack(
        [
            3 + 0.15 * np.cos(t := rng.uniform(0, 6.28, 300)),
            0.15 * np.sin(t),
            rng.uniform(-1, 2, 300),
        ]
    )
    other = rng.uniform([-5, -5, 0], [5, 5, 3], (200, 3))
    scan = np.vstack([ground, stem, other])
    cm = CloudMap(keyframe_voxel_m=0.05, voxel_m=0.05)
    cm.add_keyframe(0, 100.0, scan, ground_points=ground, stem_points=[stem], stem_tree_ids=[7])
    poses = np.stack([_pose(1000.0, np.pi / 2)])  # moved after the keyframe was added
    out = cm.build(poses)
    world_stem = stem @ poses[0][:3, :3].T + poses[0][:3, 3]
    labelled = out["points"][out["tree_id"] == 7]
    assert len(labelled) > 50
    # every stem-labelled voxel lies on the moved stem's circle (radius 0.15 m, voxels 5 cm)
    r = np.hypot(labelled[:, 0] - 1000.0, labelled[:, 1] - 3.0)
    assert np.abs(r - 0.15).max() < 0.05
    assert np.abs(world_stem[:, :2].mean(axis=0) - [1000.0, 3.0]).max() < 0.05
    ground_z = out["points"][out["classification"] == 2][:, 2]
    assert len(ground_z) > 100 and np.allclose(ground_z, -1.5)
    assert not np.any(out["classification"][out["points"][:, 2] > 0.1] == 2)
    assert np.all(out["time"] == 100.0)


def test_label_stems_prefilter_drops_only_points_beyond_every_stem():
    """label_stems' grid prefilter is exact: the labels equal a brute-force nearest-tree rule
    (points on rings just inside / outside the radius, UTM-sized offsets)."""
    rng = np.random.default_rng(4)
    for offset in (0.0, 4.5e6):
        xy = rng.uniform(-20, 20, (30, 2)) + offset
        dbh = np.where(rng.uniform(size=30) < 0.2, np.nan, rng.uniform(0.05, 0.5, 30))
        trees = {"x": xy[:, 0], "y": xy[:, 1], "dbh_m": dbh, "z": rng.uniform(-1, 1, 30)}
        trees["id"] = np.arange(1, 31)
        radius = np.where(np.isfinite(dbh), dbh / 2, 0.15) + 0.1
        angle = rng.uniform(0, 2 * np.pi, 30 * 40)
        ring = np.repeat(radius, 40) * rng.choice([0.5, 0.999, 1.001, 2.0, 4.0], 30 * 40)
        near = np.repeat(xy, 40, axis=0) + ring[:, None] * np.column_stack(
            [np.cos(angle), np.sin(angle)]
        )
        far = rng.uniform(-25, 25, (20000, 2)) + offset
        pts_xy = np.vstack([near, far])
        points = np.column_stack([pts_xy, rng.uniform(-2, 4, len(pts_xy))])
        classification = np.where(rng.uniform(size=len(points)) < 0.1, 2, 1).astype(np.uint8)
        got = label_stems(points, classification, np.zeros(len(points), np.int64), trees)
        d = np.linalg.norm(pts_xy[:, None, :] - xy[None, :, :], axis=2)
        k = d.argmin(axis=1)
        dz = points[:, 2] - trees["z"][k]
        inside = (d[np.arange(len(k)), k] <= radius[k]) & (dz >= -1.3) & (dz <= 2.7)
        want = np.where(inside & (classification != 2), trees["id"][k], 0)
        assert (want > 0).sum() > 100
        np.testing.assert_array_equal(got, want)
