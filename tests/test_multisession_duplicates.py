"""Trees mapped twice are merged after a loop closure: two landmarks that the closure brought
within each other's association gate, with compatible DBH, and never observed in one scan."""

from __future__ import annotations

import numpy as np
import pytest
from test_multisession_loop_closure import _stand, _walk

from forestslam.slam import SlamConfig
from forestslam.slam.association import duplicate_pairs


def test_duplicate_pairs_follow_the_gate_the_dbh_and_the_scans():
    xy = np.array(
        [
            [0.0, 0.0],
            [0.05, 0.0],  # one tree mapped twice: merged
            [5.0, 0.0],
            [5.04, 0.0],  # as close, but seen in one scan: two trees
            [10.0, 0.0],
            [10.5, 0.0],  # beyond the gate
            [20.0, 0.0],
            [20.03, 0.0],  # DBH 0.2 against 0.6 m
            [30.0, 0.0],
            [30.02, 0.0],
            [30.05, 0.0],  # three: the nearest two, once each
        ]
    )
    dbh = np.full(len(xy), np.nan)
    dbh[6], dbh[7] = 0.2, 0.6
    sigma = np.full(len(xy), 0.03)
    together = {(2, 3)}
    pairs = duplicate_pairs(
        xy, sigma, dbh, np.arange(len(xy)), lambda a, b: (a, b) in together, SlamConfig()
    )
    assert sorted(map(tuple, pairs.tolist())) == [(0, 1), (8, 9)]
    # only the candidates are considered (aliases already tied are left out by the caller)
    none = duplicate_pairs(xy, sigma, dbh, np.array([0, 2, 4]), lambda a, b: False, SlamConfig())
    assert len(none) == 0


def _duplicates(slam, stand) -> tuple[int, int]:
    """(untied landmark pairs on one true tree within 0.3 m, merged pairs on two trees)."""
    xy, _ = slam.landmarks()
    alias = slam.aliases()
    tree = np.argmin(np.linalg.norm(xy[:, None] - stand[None], axis=2), axis=1)
    roots = np.flatnonzero(alias < 0)
    d = np.linalg.norm(xy[roots, None] - xy[None, roots], axis=2)
    same = (tree[roots, None] == tree[None, roots]) & (d < 0.3)
    untied = int(np.triu(same, 1).sum())
    tied = np.flatnonzero(alias >= 0)
    wrong = int(np.sum(tree[tied] != tree[alias[tied]]))
    return untied, wrong


def test_duplicates_left_by_a_closure_are_merged(monkeypatch):
    stand = _stand(3)
    with monkeypatch.context() as m:
        m.setattr("forestslam.slam.landmark_slam.LandmarkSlam._merge_duplicates", lambda s, _: None)
        slam, loops, _, _ = _walk(stand, place_recognition=True)
    before, _ = _duplicates(slam, stand)
    assert loops.stats["closures"] >= 1 and before >= 3  # the closure leaves copies untied

    slam, loops, ate, _ = _walk(stand, place_recognition=True)
    after, wrong = _duplicates(slam, stand)
    assert slam.merged_duplicates >= before - after > 0
    assert after <= before // 4 and wrong == 0
    assert ate < 0.25


if __name__ == "__main__":
    pytest.main([__file__])
