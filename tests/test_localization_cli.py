"""`forestslam localize`: query schedule, frame aggregation and output files, with perception and
odometry replaced by test doubles that see a known stand from a known trajectory."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from forestslam.io import Scan, read_tum
from forestslam.localization import TreeMap
from forestslam.localization.runner import run_localization


def _stand(seed: int = 2) -> np.ndarray:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 150, (1000, 2))
    pairs = cKDTree(xy).query_pairs(2.5, output_type="ndarray")
    keep = np.ones(len(xy), bool)
    keep[pairs[:, 1]] = False
    return xy[keep]


def _pose(t: float) -> np.ndarray:
    """True T_map_sensor at time t: a slow arc through the stand."""
    yaw = 0.3 + 0.05 * t
    T = np.eye(4)
    T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T[:2, 3] = [50 + 1.0 * t * math.cos(yaw), 60 + 1.0 * t * math.sin(yaw)]
    return T


@pytest.fixture
def doubles(monkeypatch):
    stand = _stand()
    T0_inv = np.linalg.inv(_pose(0.0))
    rng = np.random.default_rng(5)

    def detect(scan, sensor, config=None):
        T = _pose(scan.stamp)
        d = np.column_stack([stand, np.zeros(len(stand)), np.ones(len(stand))]) @ np.linalg.inv(T).T
        xy = d[:, :2][np.hypot(d[:, 0], d[:, 1]) < 15.0]
        xy = xy[rng.uniform(size=len(xy)) > 0.1]
        return SimpleNamespace(xy=xy + rng.normal(0, 0.03, xy.shape))

    class Odometry:  # world = first scan's sensor frame, like the real one
        def __init__(self, sensor, config=None, perception_config=None):
            pass

        def step(self, scan):
            return SimpleNamespace(
                stamp=scan.stamp,
                T_world_sensor=T0_inv @ _pose(scan.stamp),
                stems=detect(scan, None),
            )

    def read_scans(path, topic=None, start=0, packets=None):
        return iter([Scan(0.5 * k, np.zeros((1, 3))) for k in range(12)][start:])

    import forestslam.io
    import forestslam.odometry
    import forestslam.perception

    monkeypatch.setattr(forestslam.perception, "detect", detect)
    monkeypatch.setattr(forestslam.odometry, "Odometry", Odometry)
    monkeypatch.setattr(forestslam.io, "read_scans", read_scans)
    return stand


@pytest.mark.parametrize(
    ("frames", "every", "expected_scans"), [(1, 3, [0, 3, 6, 9]), (4, 4, [3, 7, 11])]
)
def test_queries_and_outputs(doubles, tmp_path, frames, every, expected_scans):
    tree_map = TreeMap(doubles)
    csv = tmp_path / "map.csv"
    csv.write_text("x,y,dbh_m\n" + "".join(f"{x},{y},0.3\n" for x, y in doubles))
    run = run_localization("seq.bag", csv, "vlp16", tmp_path / "out", frames=frames, every=every)
    doc = json.loads((tmp_path / "out" / "localization.json").read_text())
    assert [q["scan"] for q in doc["queries"]] == expected_scans
    assert doc["map_trees"] == len(tree_map)
    for q in doc["queries"]:
        assert set(q) >= {"stamp", "accepted", "x", "y", "yaw", "inliers", "covariance"}
        assert np.asarray(q["covariance"]).shape == (3, 3)
    assert run.accepted == len(expected_scans)
    stamps, poses = read_tum(tmp_path / "out" / "localization.tum")
    assert len(stamps) == run.accepted
    for stamp, T in zip(stamps, poses, strict=True):
        truth = _pose(stamp)
        assert np.hypot(*(T[:2, 3] - truth[:2, 3])) < 0.1
        yaw = math.atan2(T[1, 0], T[0, 0])
        assert abs(math.remainder(yaw - math.atan2(truth[1, 0], truth[0, 0]), 2 * math.pi)) < 0.01


def test_keyframe_distance_spreads_the_frames(doubles, tmp_path):
    run = run_localization(
        "seq.bag", TreeMap(doubles), "vlp16", tmp_path, frames=3, every=1, keyframe_distance_m=1.0
    )
    # Consecutive frames would fill the window at scan 2; keyframes >= 1 m apart (the doubles
    # move about 0.5 m per scan) fill it later.
    assert run.queries[0]["scan"] >= 3
    assert len(run.queries) == 12 - run.queries[0]["scan"]
    assert run.accepted == len(run.queries)


def test_cli_reports_bad_arguments(doubles, tmp_path):
    from forestslam.errors import InputError

    with pytest.raises(InputError):
        run_localization("seq.bag", TreeMap(doubles), "vlp16", tmp_path, frames=0)
    with pytest.raises(InputError):
        run_localization("seq.bag", tmp_path / "none.npz", "vlp16", tmp_path)


def test_config_file_reaches_the_localizer(doubles, tmp_path):
    config = tmp_path / "config.yaml"
    config.write_text("localization:\n  min_inliers: 100000\n")
    run = run_localization(
        "seq.bag", TreeMap(doubles), "vlp16", tmp_path / "out", every=4, config_path=config
    )
    assert len(run.queries) == 3
    assert run.accepted == 0
    assert all(q["reason"] == "too few inliers" for q in run.queries)
    stamps, _ = read_tum(tmp_path / "out" / "localization.tum")
    assert len(stamps) == 0


def test_packets_decoded_by_the_profile_and_a_checkpoint_after_every_query(
    doubles, tmp_path, monkeypatch
):
    """The job skeleton: raw Velodyne packets decoded as the --sensor profile says, and after
    every query run.yaml (status running, the counts so far) and the outputs are rewritten."""
    import yaml

    import forestslam.io
    import forestslam.perception
    from forestslam.sensors import load_profile

    packets_seen, summaries = [], []
    out = tmp_path / "out"

    def read_scans(path, topic=None, start=0, packets=None):
        packets_seen.append(packets)
        return iter([Scan(0.5 * k, np.zeros((1, 3))) for k in range(6)][start:])

    detect = forestslam.perception.detect  # the fixture's double

    def detect_and_look(scan, sensor, config=None):
        summaries.append(yaml.safe_load((out / "run.yaml").read_text())["summary"])
        return detect(scan, sensor, config)

    monkeypatch.setattr(forestslam.io, "read_scans", read_scans)
    monkeypatch.setattr(forestslam.perception, "detect", detect_and_look)
    # No retry: one frame per query, so only query scans are detected (no odometry).
    run = run_localization("seq.bag", TreeMap(doubles), "vlp16", out, every=2, retry_frames=0)
    assert packets_seen == [load_profile("vlp16").packet_config()]
    assert len(run.queries) == 3  # scans 0, 2, 4
    assert [s.get("queries") for s in summaries] == [None, 1, 2]
    assert all(s["status"] == "running" for s in summaries)
    assert yaml.safe_load((out / "run.yaml").read_text())["summary"]["queries"] == 3


def test_a_rejected_query_is_retried_on_more_frames(doubles, tmp_path):
    """--retry-frames: one scan holds 16-19 trunks, too few for min_inliers 20, so every query is
    rejected at first; the retry aggregates up to 4 keyframes (20-22 trunks) and the record says
    so. The first scan has no earlier frame to retry with."""
    config = tmp_path / "config.yaml"
    config.write_text("localization:\n  min_inliers: 20\n")
    run_localization(
        "seq.bag",
        TreeMap(doubles),
        "vlp16",
        tmp_path / "out",
        config_path=config,
        keyframe_distance_m=1.0,
        retry_frames=4,
    )
    queries = json.loads((tmp_path / "out" / "localization.json").read_text())["queries"]
    assert len(queries) == 12
    assert queries[0]["frames"] == 1 and queries[0]["first_reason"] == ""
    assert not queries[0]["accepted"]
    for q in queries[1:]:
        assert q["first_reason"] == "too few inliers"
        assert 2 <= q["frames"] <= 4
    accepted = [q for q in queries if q["accepted"]]
    assert len(accepted) >= 3
    assert all(q["frames"] > 1 for q in accepted)
    for q in accepted:
        truth = _pose(q["stamp"])
        assert np.hypot(q["x"] - truth[0, 3], q["y"] - truth[1, 3]) < 0.1
    # Without the retry the same queries are all rejected (the 1-frame answer is not relabelled).
    plain = run_localization(
        "seq.bag", TreeMap(doubles), "vlp16", tmp_path / "plain", config_path=config, retry_frames=0
    )
    assert plain.accepted == 0
    assert all(q["frames"] == 1 and q["first_reason"] == "" for q in plain.queries)
    assert not any(q["retried"] for q in plain.queries)


def test_sequence_queries_are_retried_by_default(doubles, tmp_path):
    """localization.retry_frames (5) is on by default for scans: the rejected 1-frame queries
    are retried on up to 5 frames at least retry_keyframe_distance_m apart; the records and
    run.yaml's summary say which; with --frames 5 (no more frames to add) it is off."""
    import yaml

    config = tmp_path / "config.yaml"
    config.write_text("localization:\n  min_inliers: 20\n  retry_keyframe_distance_m: 1.0\n")
    out = tmp_path / "out"
    run = run_localization("seq.bag", TreeMap(doubles), "vlp16", out, config_path=config)
    doc = yaml.safe_load((out / "run.yaml").read_text())
    assert doc["retry_frames"] == 5
    retried = [q for q in run.queries if q["retried"]]
    assert len(retried) == len(run.queries) - 1  # the first scan has nothing to add
    assert doc["summary"]["retried"] == len(retried)
    assert all(2 <= q["frames"] <= 5 and q["first_reason"] for q in retried)
    assert sum(q["accepted"] for q in retried) >= 3
    wide = run_localization(
        "seq.bag", TreeMap(doubles), "vlp16", tmp_path / "wide", frames=5, config_path=config
    )
    assert not any(q["retried"] for q in wide.queries)


def test_retry_frames_must_exceed_frames(doubles, tmp_path):
    from forestslam.errors import InputError

    with pytest.raises(InputError, match="retry-frames"):
        run_localization("seq.bag", TreeMap(doubles), "vlp16", tmp_path, frames=3, retry_frames=3)


def test_still_rejected_queries_get_a_last_look_on_more_frames(doubles, tmp_path):
    """localization.retry_last_frames: one scan holds 16-19 trunks, too few for min_inliers 20;
    a query rejected on 1 frame and on retry_frames (2) is looked at a last time on up to 5
    keyframes (the machine kept driving) and found; without the last look it stays rejected."""
    config = tmp_path / "config.yaml"
    text = "localization:\n  min_inliers: 20\n  retry_keyframe_distance_m: 1.0\n  retry_frames: 2\n"
    config.write_text(text + "  retry_last_frames: 5\n")
    run = run_localization("seq.bag", TreeMap(doubles), "vlp16", tmp_path / "a", config_path=config)
    last = [q for q in run.queries if q["looks"] == 3 and q["accepted"]]
    assert last, [(q["looks"], q["frames"], q["accepted"]) for q in run.queries]
    for q in last:
        assert 2 < q["frames"] <= 5 and q["retried"] and q["first_reason"] == "too few inliers"
        truth = _pose(q["stamp"])
        assert np.hypot(q["x"] - truth[0, 3], q["y"] - truth[1, 3]) < 0.1
    assert all(q["looks"] <= 3 and q["frames"] <= 5 for q in run.queries)
    config.write_text(text + "  retry_last_frames: 0\n")
    two = run_localization("seq.bag", TreeMap(doubles), "vlp16", tmp_path / "b", config_path=config)
    by_scan = {q["scan"]: q for q in two.queries}
    assert all(not by_scan[q["scan"]]["accepted"] for q in last)
    assert all(q["looks"] <= 2 for q in two.queries)


def test_every_look_of_a_retried_query_spends_the_significance():
    """A query that may get 3 looks tests each at min_significance + log10(3): a view accepted
    alone at a level just below its significance is rejected when the retries are on (it has
    no earlier frame, so it gets no second look either)."""
    from forestslam.localization import LocalizationConfig
    from forestslam.localization.runner import _query, _QuerySetup

    stand = _stand()
    T = _pose(0.0)
    d = np.column_stack([stand, np.zeros(len(stand)), np.ones(len(stand))]) @ np.linalg.inv(T).T
    xy = d[:, :2][np.hypot(d[:, 0], d[:, 1]) < 15.0]
    scan = Scan(0.0, np.zeros((1, 3)))

    def first_look(retry_frames: int, retry_last_frames: int, cfg: LocalizationConfig) -> dict:
        q = _QuerySetup(TreeMap(stand), None, None, cfg, 1, 1, {}, retry_frames, retry_last_frames)
        return _query(q, [], [], xy, np.eye(4), scan, 0)

    alone = first_look(0, 0, LocalizationConfig())
    assert alone["accepted"] and alone["looks"] == 1
    cfg = LocalizationConfig(min_significance=alone["significance"] - 0.1)
    assert first_look(0, 0, cfg)["accepted"]
    chained = first_look(5, 7, cfg)
    assert chained["looks"] == 1 and not chained["retried"]
    assert not chained["accepted"]
    assert chained["significance"] == pytest.approx(alone["significance"])
    assert first_look(5, 0, cfg)["accepted"] is False  # 2 looks: + log10(2) = 0.3


def test_chain_significance():
    from forestslam.localization import chain_significance

    assert chain_significance(2.3, 1) == 2.3
    assert chain_significance(2.3, 3) == pytest.approx(2.3 + math.log10(3))
    with pytest.raises(ValueError):
        chain_significance(2.3, 0)
