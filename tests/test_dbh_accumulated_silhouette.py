"""Accumulated silhouette (mapping/thin_stems.py): a stem thinner than one VLP-16 azimuth step
at its range (0-1 returns per scan line) gets a DBH measured over many scans, within its
dbh_std_m; none when the scans' phases do not cover the stem or the scans have no rings."""

import numpy as np

from forestslam.mapping import thin_stems
from forestslam.mapping.config import MappingConfig
from forestslam.mapping.tree_map import AZ_BIN_RAD, TreeMap, _bin_rows
from forestslam.perception.synthetic_stems import ROUND, make_stem, scan_stems
from forestslam.sensors import load_profile

STEP = np.radians(load_profile("vlp16").azimuth_resolution_deg)
BREAST_Z = -0.5  # scan_stems: sensor 1.8 m above flat ground


def _pass(
    dbh: float,
    lateral_m: float,
    xs: np.ndarray,
    seed: int,
    same_phase: bool = False,
    stem_at: float = 10.0,
    accumulated_dbh: bool = True,
):
    """A VLP-16 drives along x past a stem of `dbh` at (stem_at, lateral_m) (a 30 cm stem
    further on); the tree map has a tree at (10, lateral_m) (1 cm noise) without a per-scan
    DBH. The accumulated DBH on unless told (MappingConfig.dbh_sweep_dbh)."""
    rng = np.random.default_rng(seed)
    world = [make_stem(stem_at, lateral_m, dbh, ROUND, rng), make_stem(14.0, -6.0, 0.3, ROUND, rng)]
    tm = TreeMap(MappingConfig(dbh_sweep_dbh=accumulated_dbh), azimuth_step_rad=STEP)
    for s, x in enumerate(xs):
        scan = scan_stems(
            world, np.array([x, 0.0]), ROUND, seed=seed if same_phase else 1000 * seed + s
        )
        T = np.eye(4)
        T[0, 3] = x
        centre = np.array([[10.0, lateral_m]]) + rng.normal(0, 0.01, 2)
        rho = np.hypot(10.0 - x, lateral_m)
        nan = np.array([np.nan])
        tm.add(
            s, T, np.array([0]), [np.zeros((0, 3))], nan, np.array([BREAST_Z]), nan, [rho], centre
        )
        if s == 0:
            tm.flush(0)
        tm.add_returns(0.1 * s, T, scan.points, scan.ring, None)
    return tm, world[0].dbh


def test_a_stem_under_one_step_is_measured_over_scans():
    """2.5-3 cm stems 10-12 m from the path: one step is 3.5-4.2 cm, so a scan line holds 0 or
    1 return. Over 80 scans the mean hits per line x step is the width: unbiased over 8 passes
    (mean error within 0.15 cm), each within 0.5 cm and 2 sigma, and about 2/3 within 1 sigma
    (the phase error of 80 scans is 0.2-0.3 cm here)."""
    errors, sigmas = [], []
    for seed, (dbh, lateral) in enumerate([(0.025, 10.0), (0.03, 12.0)] * 4):
        tm, truth = _pass(dbh, lateral, np.linspace(0.0, 20.0, 80), seed)
        tree = tm.trees[0]
        _, lines, near = np.asarray(tree.sweep, dtype=float).T
        assert near.sum() / lines.sum() < 1.0  # under one return per line: no silhouette
        assert np.isnan(tm._measured_dbh(tree)[0])
        got, std, windows = tm.dbh(0)
        assert windows == 0
        errors.append(got - truth)
        sigmas.append(std)
    errors, sigmas = np.asarray(errors), np.asarray(sigmas)
    assert abs(np.mean(errors)) < 0.0015
    assert np.max(np.abs(errors)) < 0.005
    assert np.all(np.abs(errors) <= 2 * sigmas)
    assert np.mean(np.abs(errors) <= sigmas) >= 0.5


def test_phases_that_do_not_cover_the_stem_give_no_dbh():
    """A sensor standing still sees the stem at one phase in every scan: the hits sit at one
    offset across the view ray, so the width is not measured."""
    tm, _ = _pass(0.03, 12.0, np.full(60, 5.0), seed=3, same_phase=True)
    assert len(tm.trees[0].sweep) == 60
    assert tm.sweep_estimate(tm.trees[0]) is None
    assert np.isnan(tm.dbh(0)[0])


def test_a_tree_where_no_stem_stands_is_empty():
    """With the lines counted only (accumulated DBH off): a mapped tree 1 m beside a 3 cm stem
    (a split copy) has no returns at breast height: empty, left out of the table; a 2 cm stem
    20 m from the path is not."""
    xs = np.linspace(0.0, 20.0, 60)
    tm, _ = _pass(0.03, 20.0, xs, seed=1, stem_at=11.0, accumulated_dbh=False)
    assert tm.is_empty(tm.trees[0])
    assert len(tm.table(np.array([0]), np.array([[10.0, 20.0]]), np.array([60]))["id"]) == 0
    tm, _ = _pass(0.02, 20.0, xs, seed=1, accumulated_dbh=False)
    assert not tm.is_empty(tm.trees[0])
    assert len(tm.table(np.array([0]), np.array([[10.0, 20.0]]), np.array([60]))["id"]) == 1
    assert np.isnan(tm.dbh(0)[0])  # no accumulated DBH when it is off


def test_azimuth_windows_across_the_wrap():
    """The rows of the azimuth bins within a window, also across +-pi."""
    az = np.array([-3.1, -2.0, 0.0, 0.05, 3.0, 3.12])
    bins = np.sort(np.floor((az + np.pi) / AZ_BIN_RAD))
    az = np.sort(az)
    assert list(az[_bin_rows(bins, 0.0, 0.1)]) == [0.0, 0.05]
    assert sorted(az[_bin_rows(bins, np.pi, 0.2)]) == [-3.1, 3.0, 3.12]
    assert sorted(az[_bin_rows(bins, -np.pi + 0.01, 0.1)]) == [-3.1, 3.12]


def test_scans_without_rings_or_step_count_nothing():
    """No rings (the lines are unknown) or no azimuth step: no accumulated silhouette."""
    tm = TreeMap(MappingConfig(), azimuth_step_rad=STEP)
    tm._sweep_ids = [0]
    tm.add_returns(0.0, np.eye(4), np.ones((10, 3)), None)
    assert not tm.trees
    tm = TreeMap(MappingConfig())
    tm._sweep_ids = [0]
    tm.add_returns(0.0, np.eye(4), np.ones((10, 3)), np.zeros(10, dtype=np.uint16))
    assert not tm.trees


def test_accumulated_width_is_the_mean_hits_per_line_times_the_step():
    """Known answer: 3 of 4 lines hit at a 4 cm step -> 3 cm. Blocks holding the same phases
    show no spread: the phase error of 40 independent scans is the floor (f = 0.75)."""
    s = np.full(40, 0.04)
    k = np.tile([1, 1, 1, 0], 10).astype(float)
    width, se = thin_stems.accumulated_width(s, k, np.ones(40), block_scans=4)
    assert abs(width - 0.03) < 1e-12
    assert abs(se - 0.04 * np.sqrt(40 * 0.75 * 0.25) / 40) < 1e-12
    _, se_one = thin_stems.accumulated_width(s, k, np.ones(40), block_scans=40)
    assert se_one == np.inf  # one block: no spread to estimate
