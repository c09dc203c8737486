"""Levelling a session's tilted frame on another's by the trees' heights."""

from __future__ import annotations

import numpy as np

from forestslam.geometry import rigid_fit
from forestslam.multisession.level import level_fit


def _tilted(rx_deg, ry_deg, yaw_deg, t):
    def rot(axis, deg):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        i, j = [k for k in range(3) if k != axis]
        R = np.eye(3)
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        return R

    T = np.eye(4)
    T[:3, :3] = rot(2, yaw_deg) @ rot(1, ry_deg) @ rot(0, rx_deg)
    T[:3, 3] = t
    return T


def _scene(seed=0):
    """Breast-height centres of 60 trees over 1.5 m of relief, and a sensor path 0.3 m below
    breast height across the stand, both in the world (A's) frame."""
    rng = np.random.default_rng(seed)
    ground = lambda xy: 0.02 * xy[:, 0] + 0.5 * np.sin(xy[:, 1] / 12.0)  # noqa: E731
    trees = rng.uniform(0, 60, (60, 2))
    path = np.column_stack([np.linspace(5, 55, 200), np.linspace(10, 50, 200)])
    return (
        np.column_stack([trees, ground(trees) + 1.3]),
        np.column_stack([path, ground(path) + 1.0]),
    )


def test_a_tilted_frame_is_levelled_on_tree_heights():
    trees, path = _scene()
    T_a_b = _tilted(2.5, -2.0, 40.0, [3.0, -7.0, 0.8])  # B's frame: its start, tilted
    to_b = np.linalg.inv(T_a_b)
    rng = np.random.default_rng(1)
    trees_b = trees @ to_b[:3, :3].T + to_b[:3, 3] + rng.normal(0, 0.02, trees.shape)
    path_b = path @ to_b[:3, :3].T + to_b[:3, 3]
    trees_b[3, 2] += 1.5  # one tree's height badly wrong
    T, tilt, kept = level_fit(trees_b, trees, min_trees=8, max_tilt_deg=15.0)
    assert abs(tilt - np.degrees(np.arccos(T_a_b[2, 2]))) < 0.1 and kept == 59
    err = np.linalg.norm((path_b @ T[:3, :3].T + T[:3, 3] - path)[:, :2], axis=1)
    assert err.max() < 0.02
    # what a planar placement on the trees leaves: the tilt times the height differences
    fit = rigid_fit(trees_b[:, :2], trees[:, :2])
    planar = np.linalg.norm(path_b[:, :2] @ fit[:2, :2].T + fit[:2, 2] - path[:, :2], axis=1)
    assert planar.max() > 0.04


def test_levelling_needs_heights_and_a_plausible_tilt():
    trees, _ = _scene(2)
    no_heights = trees.copy()
    no_heights[:, 2] = np.nan
    assert level_fit(no_heights, trees, 8, 15.0) is None
    assert level_fit(trees[:5], trees[:5], 8, 15.0) is None  # too few trees
    T = _tilted(25.0, 0.0, 0.0, [0, 0, 0])  # 25 deg: not a sensor's tilt on a slope
    moved = trees @ T[:3, :3].T
    assert level_fit(trees, moved, 8, 15.0) is None
    assert level_fit(trees, moved, 8, 30.0) is not None
