"""Local loop closure: trees mapped a second time after a long excursion are matched to the
trees not re-found lately by one rigid shift within the SLAM's search radius, and tied only when
that many agreeing trees are improbable by chance (`chance_significance`)."""

from __future__ import annotations

import numpy as np
from test_multisession_loop_closure import _assert_ties_are_true_trees, _stand, _walk

from forestslam.geometry import se2, transform_xy
from forestslam.localization.config import LocalizationConfig
from forestslam.multisession.loops import (
    PlaceRecognition,
    PlaceRecognitionConfig,
    chance_significance,
    local_density,
)
from forestslam.slam import SlamConfig
from forestslam.slam.association import shared_shift

RADIUS_M = 20.0


def _trees(rng: np.random.Generator, n: int) -> np.ndarray:
    """n trees uniform in the query disc (RADIUS_M)."""
    r = RADIUS_M * np.sqrt(rng.uniform(size=n))
    a = rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _significance(query: np.ndarray, mapped: np.ndarray, cfg: SlamConfig, radius: float):
    corr, pairs, tried = shared_shift(query, mapped, radius, cfg)
    if len(pairs) == 0:
        return corr, pairs, 0.0
    density = local_density(mapped, RADIUS_M)
    sig = chance_significance(len(pairs), len(query), tried, density, cfg.consensus_inlier_m)
    return corr, pairs, sig


def test_a_second_copy_of_a_place_is_found_and_significant():
    rng = np.random.default_rng(3)
    cfg = SlamConfig()
    mapped = _trees(rng, 60)  # the place, mapped on the first pass
    seen = rng.choice(len(mapped), 14, replace=False)
    drift = se2(1.1, -0.6, np.radians(1.0))  # the second pass's error on return
    copies = transform_xy(drift, mapped[seen]) + rng.normal(0, 0.05, (14, 2))
    new = _trees(rng, 30)  # trees the first pass did not map (>= 1 m from the mapped ones)
    new = new[np.min(np.linalg.norm(new[:, None] - mapped[None], axis=2), axis=1) >= 1.0]
    query = np.vstack([copies, new])
    corr, pairs, sig = _significance(query, mapped, cfg, 3.0)
    truth = {(i, int(j)) for i, j in enumerate(seen)}
    assert len(pairs) >= 12
    assert set(map(tuple, pairs.tolist())) <= truth  # every pair is the same tree
    assert sig >= 6.0
    undone = transform_xy(corr, copies) - mapped[seen]
    assert np.median(np.linalg.norm(undone, axis=1)) < 0.1


def test_chance_matches_are_as_rare_as_their_significance_says():
    """Unrelated tree sets (a new place beside an old one): the fraction of queries reaching
    significance s must not exceed 10^-s (the test is a bound on the chance probability)."""
    rng = np.random.default_rng(11)
    cfg = SlamConfig()
    sigs = []
    for _ in range(300):
        mapped = _trees(rng, int(rng.integers(20, 80)))
        query = _trees(rng, int(rng.integers(8, 40)))
        sigs.append(_significance(query, mapped, cfg, 3.0)[2])
    sigs = np.array(sigs)
    for s in (1.0, 1.5, 2.0):
        assert np.mean(sigs >= s) <= 10.0**-s, (s, np.mean(sigs >= s))
    assert sigs.max() < PlaceRecognitionConfig().local_min_significance  # never tied by chance


def test_local_density_sees_a_clump():
    rng = np.random.default_rng(5)
    clump = rng.normal(0, 1.0, (30, 2))  # 30 trees within a few metres of the disc's centre
    disc = len(clump) / (np.pi * RADIUS_M**2)
    assert local_density(clump, RADIUS_M) > 20 * disc
    assert local_density(clump[:1], RADIUS_M) == 1 / (np.pi * RADIUS_M**2)


def test_a_loop_the_global_query_cannot_verify_is_closed_locally():
    """The drifted loop of test_multisession_loop_closure (back on its first trees 2 m off)
    with every global place-recognition query refused: the local closure alone closes it, and
    every tie joins two copies of one true tree."""
    stand = _stand(3)
    refuse = LocalizationConfig(min_significance=1e9)  # no global place is ever accepted

    def walk(local: bool):
        loops = PlaceRecognition(PlaceRecognitionConfig(local_consensus=local), refuse)
        return _walk(stand, place_recognition=True, loops=loops)

    _, loops, ate_without, end_without = walk(False)
    assert loops.stats["closures"] == 0 and ate_without > 0.8 and end_without > 1.0
    slam, loops, ate, end = walk(True)
    assert loops.stats["local_closures"] >= 1 and loops.stats["closures"] == 0
    assert ate < 0.25 and end < 0.2
    _assert_ties_are_true_trees(slam, stand)
