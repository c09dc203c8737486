"""Relocalization after a tracking loss: an odometry jump breaks the chain, place recognition
places the lost segment back in the map; a segment in a place the map does not hold stays lost
and adds no constraint."""

from __future__ import annotations

import math

import numpy as np
from tree_stands import spaced_forest

from forestslam.evaluation import trajectory_errors
from forestslam.geometry import planar_pose
from forestslam.multisession.loops import PlaceRecognition, PlaceRecognitionConfig
from forestslam.slam import LandmarkSlam, SlamConfig


def _walk(trees_before, trees_after, jump_at, place_recognition, n=400, step=0.1):
    """A straight 40 m walk along x (truth), observed with exact stems within 12 m; at step
    `jump_at` the odometry jumps 4 m sideways and 20 deg, and from then on the stems seen are
    `trees_after` (the same stand, or a place the map does not hold)."""
    slam = LandmarkSlam(SlamConfig())
    loops = PlaceRecognition(PlaceRecognitionConfig()) if place_recognition else None
    truth = [planar_pose(i * step, 0.0, 0.0) for i in range(n)]
    jump = planar_pose(0.0, 4.0, math.radians(20.0))
    cov = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
    for i, T in enumerate(truth):
        odom = jump @ T if i >= jump_at else T
        trees = trees_after if i >= jump_at else trees_before
        local = trees - T[:2, 3]
        seen = local[np.linalg.norm(local, axis=1) < 12.0]
        res = slam.add_scan(i * 0.1, odom, cov, False, seen)
        if loops is not None and res.keyframe is not None:
            loops.step(slam, res.keyframe, res.T_map_sensor)
    stamps, poses = slam.trajectory()
    ate = trajectory_errors(stamps, poses, stamps, np.stack(truth))["ate_rmse_m"]
    return slam, loops, ate


def test_a_jump_breaks_the_chain_and_the_segment_is_relocalized():
    rng = np.random.default_rng(3)
    stand = spaced_forest(rng, -12.0, 52.0, 120)
    slam, loops, ate = _walk(stand, stand, jump_at=150, place_recognition=True)
    assert slam.losses == 1 and slam.relocalizations == 1 and slam.lost_since is None
    assert loops.stats["relocalizations"] == 1
    assert ate < 0.02  # exact stems: the jump is gone
    xy, _ = slam.landmarks()
    alive = slam.aliases() < 0
    d = np.linalg.norm(xy[alive][:, None] - stand[None], axis=2).min(axis=1)
    assert np.all(d < 0.05)  # the segment's second copies are one tree with the first
    # without place recognition the segment stays where the jumped odometry put it
    _, _, ate_without = _walk(stand, stand, jump_at=150, place_recognition=False)
    assert ate_without > 1.0


def test_a_segment_in_a_place_the_map_does_not_hold_stays_lost_and_ties_nothing():
    rng = np.random.default_rng(5)
    stand = spaced_forest(rng, -12.0, 52.0, 120)
    # another stand, same layout
    elsewhere = spaced_forest(np.random.default_rng(6), -12.0, 52.0, 120)
    slam, loops, _ = _walk(stand, elsewhere, jump_at=150, place_recognition=True)
    assert slam.losses == 1 and slam.lost_since is not None
    assert loops.stats["relocalization_queries"] > 5 and loops.stats["relocalizations"] == 0
    assert np.all(slam.aliases() < 0) and slam.relocalizations == 0  # no tie was added
    assert loops.stats["index_builds"] == 1  # the map before the loss is indexed once
