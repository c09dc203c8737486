"""A run started in a prior tree map: kidnapped start, an absent place, UTM coordinates, and no
constraint from a rejected localization."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from forestslam.io import read_trees_csv, read_tum, write_trees_csv

UTM = np.array([512300.0, 5123400.0])


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    from forestslam.sim import simulate

    # the bundled sample stand, a 30 m walk (about 110 scans)
    return simulate("sample", tmp_path_factory.mktemp("sim"), length_m=30.0)


def _inventory(sequence, path, offset=np.zeros(2), mirror=False):
    """The simulated stand as a field inventory (x, y, dbh_m), optionally shifted, or mirrored
    (a stand of the same density and sizes that is not this place)."""
    truth = read_trees_csv(sequence / "truth" / "trees.csv")
    x = -truth["x"] if mirror else truth["x"]
    columns = {"tree": truth["id"] + 100, "x": x + offset[0], "y": truth["y"] + offset[1]}
    write_trees_csv(path, columns | {"dbh_m": truth["dbh_m"]})
    return path


def _absolute_errors(run_dir, sequence, offset=np.zeros(2)):
    stamps, poses = read_tum(run_dir / "trajectory.tum")
    t_true, p_true = read_tum(sequence / "truth" / "trajectory.tum")
    idx = np.clip(np.searchsorted(t_true, stamps - 1e-6), 0, len(t_true) - 1)
    return np.linalg.norm(poses[:, :2, 3] - offset - p_true[idx][:, :2, 3], axis=1)


@pytest.mark.parametrize("offset", [np.zeros(2), UTM], ids=["local", "utm"])
def test_kidnapped_start_is_placed_and_tracked_in_the_map_frame(sequence, tmp_path, offset):
    from forestslam.runner import run

    prior = _inventory(sequence, tmp_path / "inventory.csv", offset)
    run(sequence / "sequence.bag", "vlp16", tmp_path / "run", progress=False, prior_map=prior)
    meta = yaml.safe_load((tmp_path / "run" / "run.yaml").read_text())
    placement = meta["prior_map"]["placement"]
    assert placement["placed"] and placement["method"] == "global localization"
    err = _absolute_errors(tmp_path / "run", sequence, offset)
    assert np.sqrt(np.mean(err**2)) < 0.10  # no alignment at all
    trees = read_trees_csv(tmp_path / "run" / "trees.csv")
    truth = read_trees_csv(prior)
    updated = trees["status"] == "updated"
    assert updated.sum() >= 20 and set(trees["status"]) <= {"new", "updated", "kept"}
    # an updated tree keeps its inventory id and sits on its inventory position
    row = {int(t): k for k, t in enumerate(truth["tree"])}
    k = np.array([row[int(i)] for i in trees["id"][updated]])
    d = np.hypot(trees["x"][updated] - truth["x"][k], trees["y"][updated] - truth["y"][k])
    assert np.median(d) < 0.05
    assert len(trees["x"]) >= len(truth["x"])  # prior trees never seen again are kept


def test_prior_map_without_the_place_keeps_the_run_in_its_own_frame(sequence, tmp_path):
    from forestslam.runner import run

    prior = _inventory(sequence, tmp_path / "mirrored.csv", mirror=True)
    run(sequence / "sequence.bag", "vlp16", tmp_path / "run", progress=False, prior_map=prior)
    placement = yaml.safe_load((tmp_path / "run" / "run.yaml").read_text())["prior_map"][
        "placement"
    ]
    assert not placement["placed"] and placement["frame"].startswith("own")
    _, poses = read_tum(tmp_path / "run" / "trajectory.tum")
    assert np.abs(poses[0][:3, 3]).max() < 0.05  # the first scan's frame, as without a map
    assert set(read_trees_csv(tmp_path / "run" / "trees.csv")["status"]) <= {"new", "kept"}


def test_a_rejected_localization_adds_no_constraint():
    from forestslam.multisession.prior import PriorMap, PriorTracker
    from forestslam.slam import LandmarkSlam

    rng = np.random.default_rng(4)
    own = rng.uniform(-15, 15, (30, 2))  # the run's trees
    elsewhere = rng.uniform(200, 260, (80, 2))  # a map of another place
    n = len(elsewhere)
    prior = PriorMap(
        xy=elsewhere,
        dbh_m=np.full(n, 0.3),
        dbh_std_m=np.full(n, np.nan),
        z=np.full(n, np.nan),
        observations=np.ones(n),
        ids=np.arange(n),
        sigma_m=np.full(n, 0.3),
        origin=np.zeros(2),
        source="test",
    )
    slam = LandmarkSlam()
    slam._lm_xy = own  # a graph's trees, as the SLAM has them
    slam._lm_nobs = np.full(len(own), 5)
    tracker = PriorTracker(prior)
    tracker.maybe_place(slam, keyframe=0, T_odom_sensor=np.eye(4), scan=10, stamp=1.0)
    assert tracker.placement["attempts"] == 1 and tracker.placement["rejected"] == 1
    assert not tracker.placed and np.all(tracker.prior_landmarks < 0)
    assert slam.n_landmarks == len(own)  # nothing was added to the graph
