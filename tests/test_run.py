"""The pipeline runner and `forestslam run`: outputs, modes, corrupt input, kill mid-run.

The odometry here is a test double with the documented `Odometry(sensor, config).step(scan)`
interface: it returns the true pose of a circular drive (with a yaw drift) and the stems a
perfect detector would see, so these tests check the runner, SLAM and mapping on known answers
independently of the registration code (tests/test_run_e2e.py runs the real chain).
"""

import math
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
import yaml

from forestslam.evaluation.report import evaluate_run
from forestslam.geometry import planar_pose
from forestslam.io import read_trees_csv, read_tum, write_trees_csv, write_tum

REPO = Path(__file__).resolve().parents[1]
RATE = 10.0
RADIUS = 8.0
SPEED = 1.0


def truth_pose(t):
    a = SPEED * t / RADIUS
    return planar_pose(RADIUS * math.cos(a), RADIUS * math.sin(a), a + math.pi / 2, z=1.0)


def make_trees():
    rng = np.random.default_rng(5)
    ang = np.linspace(0, 2 * np.pi, 14, endpoint=False)
    r = np.where(np.arange(14) % 2 == 0, RADIUS - 3.0, RADIUS + 3.5) + rng.uniform(-0.5, 0.5, 14)
    xy = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    dbh = rng.uniform(0.15, 0.45, 14)
    return xy, dbh


class FakeOdometry:
    """Truth pose with 0.1 deg/m of yaw drift; stems of trees within 10 m, ground points."""

    delay_s = 0.0

    def __init__(self, sensor, config=None, perception_config=None, stem_fits=True):
        self.trees_xy, self.trees_dbh = make_trees()
        self.rng = np.random.default_rng(0)
        self.prev = None
        self.drifted = None

    def step(self, scan):
        time.sleep(self.delay_s)
        T = truth_pose(scan.stamp)
        if self.prev is None:
            self.drifted = T.copy()
        else:
            rel = np.linalg.inv(self.prev) @ T
            d = np.linalg.norm(rel[:2, 3])
            bias = planar_pose(0.0, 0.0, math.radians(0.1) * d)
            self.drifted = self.drifted @ rel @ bias
        self.prev = T
        local = (self.trees_xy - T[:2, 3]) @ T[:2, :2]
        vis = np.linalg.norm(local, axis=1) < 10.0
        points, centres = [], local[vis] + self.rng.normal(scale=0.02, size=(int(vis.sum()), 2))
        for c, d in zip(local[vis], self.trees_dbh[vis], strict=True):
            facing = math.atan2(-c[1], -c[0])
            ang = facing + self.rng.uniform(-1.3, 1.3, 60)
            r = d / 2 + self.rng.normal(scale=0.005, size=60)
            points.append(
                np.column_stack(
                    [
                        c[0] + r * np.cos(ang),
                        c[1] + r * np.sin(ang),
                        self.rng.uniform(-0.2, 0.6, 60),
                    ]
                )
            )
        g = np.mgrid[-8:8:0.5, -8:8:0.5].reshape(2, -1).T
        stems = types.SimpleNamespace(
            xy=centres,
            dbh=self.trees_dbh[vis] + self.rng.normal(scale=0.02, size=len(centres)),
            z=np.full(len(centres), 0.3),
            points=points,
            base_z=np.full(len(centres), -1.0),
            ground=np.column_stack([g, np.full(len(g), -1.0)]),
        )
        return types.SimpleNamespace(
            stamp=scan.stamp,
            T_world_sensor=self.drifted.copy(),
            covariance=np.diag([1e-4, 1e-4, 1e-5]),
            degraded=False,
            stems=stems,
            timing={"perception": 1.0, "registration": 2.0},
        )


def install_fake(monkeypatch=None, delay_s=0.0):
    import forestslam.odometry as real

    module = types.ModuleType("forestslam.odometry")
    module.__path__ = real.__path__  # its submodules (config, deskew) stay the real ones
    FakeOdometry.delay_s = delay_s
    module.Odometry = FakeOdometry
    if monkeypatch is not None:
        monkeypatch.setitem(sys.modules, "forestslam.odometry", module)
    else:
        sys.modules["forestslam.odometry"] = module


def make_input(folder: Path, n: int, corrupt: int | None = None) -> tuple[Path, Path]:
    """n tiny .npy scans at 10 Hz and a truth dir (trajectory.tum, trees.csv)."""
    scans = folder / "scans"
    scans.mkdir(parents=True)
    for i in range(n):
        np.save(scans / f"{i:06d}.npy", np.ones((10, 3)) * (i + 1))  # >= 10 points, not at 0
    if corrupt is not None:
        (scans / f"{corrupt:06d}.npy").write_bytes(b"not a numpy file")
    truth = folder / "truth"
    stamps = np.arange(n) / RATE
    write_tum(truth / "trajectory.tum", stamps, np.stack([truth_pose(t) for t in stamps]))
    xy, dbh = make_trees()
    write_trees_csv(
        truth / "trees.csv",
        {
            "id": np.arange(len(xy)),
            "x": xy[:, 0],
            "y": xy[:, 1],
            "z_ground": np.zeros(len(xy)),
            "dbh_m": dbh,
            "height_m": np.full(len(xy), 20.0),
        },
    )
    return scans, truth


def test_run_slam_outputs_and_accuracy(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    n = int(2 * math.pi * RADIUS / SPEED * RATE) + 20  # one loop and a bit
    scans, truth = make_input(tmp_path, n, corrupt=7)
    out = tmp_path / "out"
    s = run(scans, "vlp16", out, mode="slam", progress=False)
    assert s.status == "complete" and s.scans == n - 1
    assert s.read_stats["skipped"] == 1  # the corrupt file, counted
    for name in (
        "trajectory.tum",
        "odometry.tum",
        "trees.csv",
        "trees.geojson",
        "map.png",
        "timing.json",
        "run.yaml",
    ):
        assert (out / name).is_file(), name
    meta = yaml.safe_load((out / "run.yaml").read_text())
    assert meta["summary"]["status"] == "complete" and meta["config"]["slam"]
    # No place recognition here: no loop closure; re-association corrections are counted apart.
    assert meta["summary"]["loop_closures"] == 0
    assert isinstance(meta["summary"]["reassociation_corrections"], int)
    # a clean walk: no loss, no move onto older copies declined
    assert meta["place_recognition"]["tracking_losses"] == 0
    assert meta["place_recognition"]["revisits"] == 0
    stamps, poses = read_tum(out / "trajectory.tum")
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-6)  # first scan's sensor frame
    m = evaluate_run(out, truth, plot=False)
    assert m["odometry"]["ate_rmse_m"] > 0.1  # the drift SLAM has to remove
    assert m["trajectory"]["ate_rmse_m"] < 0.05
    assert m["trees"]["recall"] == 1.0 and m["trees"]["precision"] == 1.0
    # the median of the per-scan DBHs (2 cm noise each) or the windowed circle fits
    assert m["trees"]["dbh_mae_m"] < 0.01
    trees = read_trees_csv(out / "trees.csv")
    assert list(trees) == ["id", "x", "y", "z", "dbh_m", "dbh_std_m", "observations"]


def test_run_map3d_and_odometry_modes(tmp_path, monkeypatch):
    from forestslam.runner import run

    install_fake(monkeypatch)
    scans, _ = make_input(tmp_path, 60)
    out = tmp_path / "m3"
    s = run(scans, "vlp16", out, mode="map3d", progress=False)
    assert s.icp_accepted > 0.8 * s.keyframes  # scan-to-map ICP refined the keyframes
    for name in ("ground.ply", "dtm.npz", "dtm.csv", "dtm.png", "trees.csv"):
        assert (out / name).is_file(), name
    dtm = np.load(out / "dtm.npz")
    z = dtm["z"][np.isfinite(dtm["z"])]
    assert len(z) > 100 and np.allclose(z, -1.0, atol=0.05)  # flat ground 1 m below sensor
    out2 = tmp_path / "od"
    run(scans, "vlp16", out2, mode="odometry", progress=False, start=10, max_scans=20)
    assert len(read_tum(out2 / "odometry.tum")[0]) == 20
    assert not (out2 / "trees.csv").exists()


SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from test_run import install_fake
install_fake(delay_s=0.03)
from forestslam.cli.main import main
sys.argv = ["forestslam", "run", {scans!r}, "--sensor", "vlp16", "--out", {out!r},
            "--config", {cfg!r}, "--no-progress"]
main()
"""


def test_killed_run_leaves_valid_outputs(tmp_path):
    scans, _ = make_input(tmp_path, 1000)
    out = tmp_path / "killed"
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mapping:\n  checkpoint_every_scans: 20\n")
    script = SCRIPT.format(tests=str(REPO / "tests"), scans=str(scans), out=str(out), cfg=str(cfg))
    path = [str(REPO / "python")] + os.environ.get("PYTHONPATH", "").split(os.pathsep)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in path if p))
    proc = subprocess.Popen(
        [sys.executable, "-c", script], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        if (out / "trajectory.tum").is_file() and len(read_tum(out / "trajectory.tum")[0]) >= 60:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    _, err = proc.communicate()
    assert proc.returncode == -signal.SIGKILL, err.decode()[-2000:]
    stamps, poses = read_tum(out / "trajectory.tum")
    assert len(stamps) >= 60 and len(stamps) % 20 == 0 and len(stamps) < 999
    assert np.all(np.diff(stamps) > 0)
    trees = read_trees_csv(out / "trees.csv")
    assert len(trees["x"]) >= 1 and np.isfinite(trees["x"]).all()
    assert len(read_tum(out / "odometry.tum")[0]) == len(stamps)
    meta = yaml.safe_load((out / "run.yaml").read_text())
    assert meta["summary"]["status"] == "running"
    # Counts as of the last checkpoint (run.yaml follows the trajectory, so it may lag one).
    assert 20 <= meta["summary"]["scans"] <= len(stamps) and meta["summary"]["scans"] % 20 == 0
    assert meta["summary"]["read_stats"]
    # A kill inside a write may leave a hidden `.name.XXXX.tmp`; the next run removes it.


def test_run_bad_inputs(tmp_path, monkeypatch):
    from forestslam.errors import InputError
    from forestslam.runner import run

    install_fake(monkeypatch)
    with pytest.raises(InputError):
        run(tmp_path / "missing.bag", "vlp16", tmp_path / "o")
    scans, _ = make_input(tmp_path, 5)
    with pytest.raises(InputError):
        run(scans, "vlp16", tmp_path / "o", mode="fly")
    with pytest.raises(InputError):
        run(scans, "vlp16", tmp_path / "o", start=100, progress=False)  # nothing left


def test_corrupt_message_mid_bag_is_skipped_and_counted_in_the_report(tmp_path, monkeypatch):
    """`forestslam run` on a ROS1 bag with one truncated message: the run completes without
    it, run.yaml counts it, the CLI's last line reports it."""
    from rosbags.rosbag1 import Writer
    from typer.testing import CliRunner

    from forestslam.cli.main import app
    from forestslam.io import Scan
    from forestslam.io.bags import POINTCLOUD2, _message, _typestore

    install_fake(monkeypatch)
    n, bad = 40, 17
    store = _typestore(True)
    bag = tmp_path / "corrupt.bag"
    with Writer(bag) as writer:
        conn = writer.add_connection("/velodyne_points", POINTCLOUD2, typestore=store)
        for k in range(n):
            m = 50
            scan = Scan(
                k / RATE,
                np.full((m, 3), float(k + 1)),  # not at the origin
                np.zeros(m, np.float32),
                np.zeros(m, np.uint16),
                np.linspace(0.0, 0.09, m),
            )
            ns, msg = _message(store, True, scan, k, "velodyne")
            raw = bytes(store.serialize_ros1(msg, POINTCLOUD2))
            writer.write(conn, ns, raw[:200] if k == bad else raw)  # cut inside the points
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app, ["run", str(bag), "--sensor", "vlp16", "--out", str(out), "--no-progress"]
    )
    assert res.exit_code == 0, res.output
    assert "1 corrupt messages skipped" in res.output
    meta = yaml.safe_load((out / "run.yaml").read_text())
    assert meta["summary"]["status"] == "complete"
    assert meta["summary"]["scans"] == n - 1
    assert meta["summary"]["read_stats"]["skipped"] == 1
    stamps, _ = read_tum(out / "odometry.tum")
    assert len(stamps) == n - 1 and not np.any(np.isclose(stamps, bad / RATE))
