"""Calibrated acceptance of global localization: absent places rejected, stage and runner-up
reported, decisions independent of the trunk order."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_localization import observe, stand, yaw_error

from forestslam.errors import InputError
from forestslam.localization import LocalizationConfig, build_map, localize


@pytest.fixture(scope="module")
def forest():
    xy = stand(800, 200.0, seed=1)
    return xy, build_map(xy)


def test_poisson_tail_matches_scipy():
    from scipy.stats import poisson

    from forestslam import _core

    for mu, k in [(0.1, 1), (0.5, 4), (2.0, 10), (7.5, 12), (0.02, 9)]:
        expected = -math.log10(poisson.sf(k - 1, mu))
        assert _core.poisson_tail_log10(mu, k) == pytest.approx(expected, rel=1e-6)
    assert _core.poisson_tail_log10(3.0, 0) == 0.0


def test_significance_is_corrected_for_seeds_and_search():
    from forestslam import _core

    base = _core.chance_significance(12, 20, 1.0, 6, 1)
    assert _core.chance_significance(12, 20, 1.0, 6, 100) == pytest.approx(base - 2.0)
    # The 6 seed points are inliers by construction: 6 inliers of a star carry no evidence.
    assert _core.chance_significance(6, 20, 1.0, 6, 1) == pytest.approx(0.0)
    # A denser map (more chance inliers expected) makes the same count less significant.
    assert _core.chance_significance(12, 20, 3.0, 6, 1) < base


def test_absent_places_are_rejected(forest):
    """Views of three other stands (sparser, same, denser) driven through the map's extent:
    none may be accepted (fixed seeds)."""
    _, tree_map = forest
    accepted = 0
    for s, (n, spacing) in enumerate([(400, 2.0), (800, 2.0), (1600, 1.5)]):
        other = stand(n, 200.0, seed=100 + s, spacing=spacing)
        for q in range(12):
            pose = (30.0 + 12 * q, 40.0 + 10 * s, 0.5 * q)
            for frames_radius in (15.0, 25.0):
                local = observe(other, pose, frames_radius, 0.05, 0.1, 2, seed=10 * q + s)
                loc = localize(tree_map, local)
                accepted += loc.accepted
                assert loc.significance < 2.3 or loc.rejected
    assert accepted == 0


def test_present_place_is_significant_and_reports_the_star_stage(forest):
    xy, tree_map = forest
    truth = (120.0, 80.0, -2.0)
    local = observe(xy, truth, 20.0, noise=0.05, miss=0.15, outliers=3, seed=4)
    loc = localize(tree_map, local)
    assert loc.accepted and loc.stage == "star"
    assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.1
    assert yaw_error(loc.yaw, truth[2]) < math.radians(0.5)
    assert loc.significance >= LocalizationConfig().min_significance
    assert 0 < loc.expected_chance_inliers < 2
    # The runner-up, when there is one, is distinct and much weaker.
    if loc.runner_up.exists:
        d = math.hypot(loc.runner_up.x - loc.x, loc.runner_up.y - loc.y)
        assert d > 1.0 or yaw_error(loc.runner_up.yaw, loc.yaw) > math.radians(5)
        assert loc.runner_up.inliers < 0.8 * loc.inliers
        assert loc.runner_up.significance < loc.significance
    d = loc.to_dict()
    assert d["stage"] == "star" and "runner_up" in d and d["significance"] == loc.significance


def test_triangle_fallback_answers_are_marked_and_optional(forest):
    """Small views (too few trunks for an unbroken star) are answered by the fallback: marked
    'triangle', held to the same significance, absent when the fallback is off."""
    xy, tree_map = forest
    rng = np.random.default_rng(3)
    stages = []
    for q in range(40):
        truth = (rng.uniform(40, 160), rng.uniform(40, 160), rng.uniform(-3, 3))
        local = observe(xy, truth, 9.0, noise=0.03, miss=0.3, outliers=1, seed=200 + q)
        on = localize(tree_map, local)
        off = localize(tree_map, local, LocalizationConfig(triangle_fallback=False))
        assert off.stage != "triangle"
        if on.accepted:
            assert on.stage in ("star", "triangle")
            assert on.significance >= LocalizationConfig().min_significance
            assert math.hypot(on.x - truth[0], on.y - truth[1]) < 0.5
            stages.append(on.stage)
    assert "triangle" in stages


def test_no_hypothesis_has_no_stage(forest):
    loc = localize(forest[1], np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]]) + 1e4)
    assert loc.rejected and loc.stage in ("", "triangle", "star")
    loc = localize(forest[1], np.zeros((0, 2)))
    assert loc.stage == "" and loc.significance == 0.0


def test_decision_invariant_to_trunk_order(forest):
    xy, tree_map = forest
    other = stand(800, 200.0, seed=55)
    for source, pose in ((xy, (70.0, 60.0, 0.9)), (other, (100.0, 100.0, 0.3))):
        local = observe(source, pose, 20.0, noise=0.05, miss=0.15, outliers=3, seed=5)
        perm = np.random.default_rng(9).permutation(len(local))
        a, b = localize(tree_map, local), localize(tree_map, local[perm])
        assert a.accepted == b.accepted and a.stage == b.stage
        assert a.significance == pytest.approx(b.significance, abs=1e-9)
        if a.accepted:
            assert (a.x, a.y, a.yaw) == pytest.approx((b.x, b.y, b.yaw), abs=1e-9)


def test_paper_matcher_finds_a_present_place_and_rejects_an_absent_one(forest):
    xy, tree_map = forest
    paper = LocalizationConfig(matcher="paper")
    truth = (100.0, 90.0, 1.2)
    local = observe(xy, truth, 25.0, noise=0.03, miss=0.05, outliers=0, seed=8)
    loc = localize(tree_map, local, paper)
    assert loc.accepted and loc.stage == "star" and loc.matched_triangles >= 2
    assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.1
    other = stand(800, 200.0, seed=77)
    absent = observe(other, truth, 25.0, noise=0.03, miss=0.05, outliers=0, seed=8)
    assert localize(tree_map, absent, paper).rejected
    assert paper.trunk_height_offset_m == 2.0 and LocalizationConfig().trunk_height_offset_m == 1.0


def test_unknown_matcher_is_an_input_error():
    from forestslam.config_utils import from_dict
    from forestslam.errors import InputError

    with pytest.raises(InputError, match="matcher.*default, paper"):
        from_dict(LocalizationConfig, {"matcher": "icp"})


def _views_found_with_and_without(option, queries, step, view, **fixed):
    """Views of a sparse stand (0.01 /m^2) localized with `option` on and off (the `fixed`
    options as given): how many are accepted (each within 0.3 m of the truth); views of
    another stand must stay rejected."""
    xy = stand(400, 200.0, seed=3, spacing=4.0)
    other = stand(400, 200.0, seed=33, spacing=4.0)
    tree_map = build_map(xy)
    found = {True: 0, False: 0}
    for on in (True, False):
        config = LocalizationConfig(**{option: on}, **fixed)
        for q in range(queries):
            truth = (40.0 + step[0] * q, 60.0 + step[1] * q, 0.5 * q)
            loc = localize(tree_map, observe(xy, truth, *view, seed=q), config)
            if loc.accepted:
                assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.3
                found[on] += 1
            assert localize(tree_map, observe(other, truth, *view, seed=q), config).rejected
    return found


def test_closeness_of_the_fit_is_evidence_in_a_sparse_view():
    """Few trunks in a sparse stand: counted in the 0.5 m gate they prove little, but a true
    pose puts them within centimetres. With the closeness evidence more views are found, none
    wrong, and views of another stand stay rejected (fixed seeds)."""
    found = _views_found_with_and_without("closeness_evidence", 12, (10, 5), (13.0, 0.03, 0.1, 1))
    assert found[True] > found[False]


def test_seed_match_closeness_is_evidence_in_a_sparse_view():
    """A few trunks of a sparse stand (30 % missed): the seed triangle or star of a true pose
    matches its map shape within the noise, a chance one anywhere in the tolerance. With the
    seed evidence more views are found, none wrong, and views of another stand stay rejected:
    on its own (without the inliers' closeness) and beside it."""
    view = (12.0, 0.05, 0.3, 1)
    alone = _views_found_with_and_without(
        "seed_evidence", 20, (6, 4), view, closeness_evidence=False
    )
    assert alone[True] > alone[False]
    found = _views_found_with_and_without("seed_evidence", 20, (6, 4), view)
    assert found[True] >= found[False] + 4


def test_views_of_exactly_four_trunks_are_found_and_absent_ones_stay_rejected():
    """A sparse stand (0.01 /m^2), 12 m views holding exactly 4 map trunks and one false trunk:
    a triangle and one trunk more. The triangle's shape agreement tested against the whole
    searched cube of side differences finds 84 of the 96 views, none wrong (71 against the
    cube's inscribed ball); the same poses in another stand stay rejected (fixed seeds)."""
    xy = stand(400, 200.0, seed=3, spacing=4.0)
    other = stand(400, 200.0, seed=33, spacing=4.0)
    tree_map = build_map(xy)
    rng = np.random.default_rng(4)
    views = found = 0
    for q in range(400):
        truth = (rng.uniform(30, 170), rng.uniform(30, 170), rng.uniform(-3, 3))
        if (np.hypot(*(xy - truth[:2]).T) <= 12.0).sum() != 4:
            continue
        views += 1
        loc = localize(tree_map, observe(xy, truth, 12.0, 0.05, 0.0, 1, seed=q))
        if loc.accepted:
            assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.3
            found += 1
        assert localize(tree_map, observe(other, truth, 12.0, 0.05, 0.0, 1, seed=q)).rejected
    assert views == 96
    assert found >= 80


def _view_with_dbh(trees, dbh, truth, seed, dbh_noise, local=None):
    """A sparse view (14 m, half the trunks missed; or `local` as given) and the trunks'
    measured DBH (a fake trunk's is random)."""
    from scipy.spatial import cKDTree

    local = observe(trees, truth, 14.0, 0.05, 0.5, 1, seed=seed) if local is None else local
    c, s = math.cos(truth[2]), math.sin(truth[2])
    world = local @ np.array([[c, s], [-s, c]]) + truth[:2]
    d, i = cKDTree(trees).query(world)
    rng = np.random.default_rng(seed)
    measured = np.where(d < 0.5, dbh[i], rng.uniform(0.08, 0.6, len(world)))
    return local, measured + rng.normal(0, dbh_noise, len(world))


def test_dbh_agreement_is_evidence_when_both_sides_have_it():
    """With a DBH on both sides, agreeing diameters raise the significance of a true pose;
    random ones do not (they agree no better than chance); views of another stand with
    their DBH stay rejected; nothing wrong is accepted (fixed seeds)."""
    rng = np.random.default_rng(4)
    xy = stand(400, 200.0, seed=3, spacing=4.0)
    other = stand(400, 200.0, seed=33, spacing=4.0)
    dbh, other_dbh = rng.uniform(0.08, 0.6, len(xy)), rng.uniform(0.08, 0.6, len(other))
    tree_map = build_map(xy, dbh)
    gain, random_gain = [], []
    for q in range(24):
        truth = (40.0 + 5 * q, 50.0 + 4 * q, 0.5 * q)
        local, local_dbh = _view_with_dbh(xy, dbh, truth, q, 0.02)
        plain = localize(tree_map, local)
        with_dbh = localize(tree_map, local, local_dbh_m=local_dbh)
        noise = localize(tree_map, local, local_dbh_m=rng.uniform(0.08, 0.6, len(local)))
        assert plain.dbh_pairs == 0
        for loc in (plain, with_dbh, noise):
            if loc.accepted:
                assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.3
        if plain.inliers >= 4 and with_dbh.inliers == plain.inliers:
            assert with_dbh.dbh_pairs > 0
            gain.append(with_dbh.significance - plain.significance)
            random_gain.append(noise.significance - plain.significance)
        absent, absent_dbh = _view_with_dbh(other, other_dbh, truth, q, 0.02)
        assert localize(tree_map, absent, local_dbh_m=absent_dbh).rejected
    assert len(gain) >= 10
    assert np.mean(gain) > 0.4
    assert np.mean(random_gain) < 0.25  # chance agreement: about nothing gained
    assert np.mean(gain) > np.mean(random_gain) + 0.3


def test_dbh_needs_both_sides_and_one_value_per_trunk(forest):
    xy, tree_map = forest  # a map without DBH
    local = observe(xy, (100.0, 100.0, 0.3), 20.0, 0.03, 0.1, 1, seed=2)
    loc = localize(tree_map, local, local_dbh_m=np.full(len(local), 0.3))
    assert loc.accepted and loc.dbh_pairs == 0
    with pytest.raises(InputError, match="one value per trunk"):
        localize(tree_map, local, local_dbh_m=np.full(len(local) + 1, 0.3))


def _sparse_views_with_dbh(n_trunks: int):
    """A sparse stand with DBHs (and another stand) and the seeded views of exactly `n_trunks`
    map trunks within 12 m: per view its true pose, the view, its measured DBHs (2 cm noise),
    the same pose's view of the other stand with its DBHs, and the view's seed."""
    xy = stand(400, 200.0, seed=3, spacing=4.0)
    other = stand(400, 200.0, seed=33, spacing=4.0)
    rng = np.random.default_rng(4)
    dbh, other_dbh = rng.uniform(0.08, 0.6, len(xy)), rng.uniform(0.08, 0.6, len(other))
    tree_map = build_map(xy, dbh)
    poses = np.random.default_rng(5)
    views = []
    for q in range(400):
        truth = (poses.uniform(30, 170), poses.uniform(30, 170), poses.uniform(-3, 3))
        if (np.hypot(*(xy - truth[:2]).T) <= 12.0).sum() != n_trunks:
            continue
        local = observe(xy, truth, 12.0, 0.05, 0.0, 1, seed=q)
        _, measured = _view_with_dbh(xy, dbh, truth, q, 0.02, local=local)
        absent = observe(other, truth, 12.0, 0.05, 0.0, 1, seed=q)
        _, absent_dbh = _view_with_dbh(other, other_dbh, truth, q, 0.02, local=absent)
        views.append((truth, local, measured, (absent, absent_dbh), q))
    return tree_map, views


def _found(tree_map, views, query_dbhs) -> dict[str, int]:
    """Views accepted per kind of query DBH (name -> function of the view and its measured
    DBHs); every accepted view is within 0.3 m, every view of the other stand is rejected."""
    found = dict.fromkeys(query_dbhs, 0)
    for truth, local, measured, (absent, absent_dbh), q in views:
        for key, dbh_of in query_dbhs.items():
            loc = localize(tree_map, local, local_dbh_m=dbh_of(local, measured, q))
            if loc.accepted:
                assert math.hypot(loc.x - truth[0], loc.y - truth[1]) < 0.3
                found[key] += 1
        assert localize(tree_map, absent, local_dbh_m=absent_dbh).rejected
    return found


def test_dbh_likelihood_ratio_finds_four_trunk_views_and_costs_little_when_useless():
    """Views of exactly 4 trunks (a triangle and one more) in a sparse stand with DBHs on both
    sides (2 cm noise): each inlier's DBH weighed by its likelihood ratio against its map
    neighbourhood's DBHs finds all 76 views (positions alone 62; the earlier rank test 73),
    none wrong; random query DBHs (useless as a whole) lose at most a tenth of the views (6;
    the rank test lost 20); views of another stand with their DBHs stay rejected."""
    tree_map, views = _sparse_views_with_dbh(4)
    found = _found(
        tree_map,
        views,
        {
            "xy": lambda local, measured, q: None,
            "dbh": lambda local, measured, q: measured,
            "random": lambda local, measured, q: np.random.default_rng(q).uniform(
                0.08, 0.6, len(local)
            ),
        },
    )
    assert len(views) == 76
    assert found["dbh"] == len(views) > found["xy"]
    assert found["random"] >= found["xy"] - len(views) / 10


def test_three_trunk_views_with_dbh_can_be_significant():
    """Views of exactly 3 trunks (and one false trunk) in a sparse stand: three positions give
    only a triangle's shape and are always rejected; with their DBHs (2 cm noise) the shape and
    three DBH agreements are significant for most views (43 of 71; min_inliers_with_dbh 3),
    none wrong; views of another stand with their DBHs stay rejected (fixed seeds)."""
    tree_map, views = _sparse_views_with_dbh(3)
    found = _found(
        tree_map,
        views,
        {"xy": lambda local, measured, q: None, "dbh": lambda local, measured, q: measured},
    )
    assert found["xy"] == 0
    assert found["dbh"] >= 0.55 * len(views)
