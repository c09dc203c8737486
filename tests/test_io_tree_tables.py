"""Tree tables of other mappers (RealtimeTrees / TreeLoc layout and the packed table): reading,
levelling by stem axes, use as a map and as queries (small tables written by the test)."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_localization import stand

from forestslam.errors import InputError
from forestslam.io.tree_tables import is_tree_table, level_rotation, read_tree_table

COLUMNS = (
    "location_x,location_y,location_z,dbh,dbh_approximation,score,reconstructed,"
    "number_clusters," + ",".join(f"axis_{r}{c}" for r in range(3) for c in range(3))
)


def frame_poses(n: int, seed: int) -> list[np.ndarray]:
    """T_world_frame along a line through the stand, each tilted 5-20 deg (a hand-held mapper)."""
    rng = np.random.default_rng(seed)
    poses = []
    for k in range(n):
        tilt = rng.uniform(5, 20)
        axis = rng.normal(size=2)
        R = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)) * Rotation.from_rotvec(
            np.radians(tilt) * np.r_[axis / np.linalg.norm(axis), 0]
        )
        T = np.eye(4)
        T[:3, :3] = R.as_matrix()
        T[:3, 3] = [40.0 + 6 * k, 50.0 + 2 * k, 1.5]
        poses.append(T)
    return poses


def frame_rows(world_xy: np.ndarray, T: np.ndarray, rng, radius: float = 20.0) -> list[str]:
    """The trees within radius of pose T as RealtimeTrees would list them in frame T."""
    near = world_xy[np.hypot(*(world_xy - T[:2, 3]).T) <= radius]
    R_frame_world = T[:3, :3].T
    rows = []
    for x, y in near:
        p = R_frame_world @ (np.array([x, y, 1.3]) - T[:3, 3])
        lean = Rotation.from_rotvec(np.r_[rng.normal(0, np.radians(3), 2), 0]).as_matrix()
        axes = R_frame_world @ lean  # third column: the stem direction in the frame
        dbh = "" if rng.uniform() < 0.3 else "0.31"
        cells = [*p, dbh, 0.3, 0.5, int(dbh != ""), 3, *axes.reshape(-1)]
        rows.append(",".join(str(c) for c in cells))
    return rows


def tum_lines(poses) -> str:
    out = []
    for k, T in enumerate(poses):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        out.append(" ".join(str(v) for v in (float(k), *T[:3, 3], *q)))
    return "# timestamp x y z qx qy qz qw\n" + "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def world():
    return stand(700, 160.0, seed=21)


def write_layout(root, world_xy, poses, seed):
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    for k, T in enumerate(poses):
        rows = frame_rows(world_xy, T, rng)
        (root / f"TreeManagerState_{k}.csv").write_text(COLUMNS + "\n" + "\n".join(rows) + "\n")
    (root / "trajectory.txt").write_text(tum_lines(poses))
    return root


def test_reads_the_realtimetrees_layout(tmp_path, world):
    poses = frame_poses(4, seed=1)
    root = write_layout(tmp_path / "session", world, poses, seed=2)
    assert is_tree_table(root)
    table = read_tree_table(root)
    assert list(table.frames) == [0, 1, 2, 3]
    assert table.poses.shape == (4, 4, 4)
    np.testing.assert_allclose(table.poses[2], poses[2], atol=1e-9)
    rows = table.rows(1)
    # Positions back in the world frame through the reference pose.
    world_pts = table.xyz[rows] @ poses[1][:3, :3].T + poses[1][:3, 3]
    from scipy.spatial import cKDTree

    assert cKDTree(world).query(world_pts[:, :2])[0].max() < 1e-6
    # dbh empty -> dbh_approximation; the axis is a unit vector.
    assert np.isfinite(table.dbh_m).all()
    assert set(np.round(table.dbh_m, 2)) <= {0.3, 0.31}
    np.testing.assert_allclose(np.linalg.norm(table.axis, axis=1), 1.0, atol=1e-9)


def test_packed_table_is_the_same(tmp_path, world):
    poses = frame_poses(3, seed=3)
    root = write_layout(tmp_path / "layout", world, poses, seed=4)
    a = read_tree_table(root)
    packed = tmp_path / "packed"
    packed.mkdir()
    lines = ["frame," + COLUMNS]
    for k in range(3):
        body = (root / f"TreeManagerState_{k}.csv").read_text().splitlines()[1:]
        lines += [f"{k},{row}" for row in body]
    with gzip.open(packed / "trees.csv.gz", "wt") as f:
        f.write("\n".join(lines) + "\n")
    (packed / "trajectory.tum").write_text(tum_lines(poses))
    b = read_tree_table(packed)
    np.testing.assert_array_equal(a.frame, b.frame)
    np.testing.assert_allclose(a.xyz, b.xyz)
    np.testing.assert_allclose(a.poses, b.poses)


def test_levelling_by_stem_axes_recovers_the_tilt(tmp_path, world):
    poses = frame_poses(5, seed=5)
    table = read_tree_table(write_layout(tmp_path / "s", world, poses, seed=6))
    for k, T in enumerate(poses):
        R = level_rotation(table.axis[table.rows(k)])
        up_in_frame = T[:3, :3].T @ [0, 0, 1.0]
        # R turns the frame's true vertical to +z (stems lean 3 deg at random).
        assert math.degrees(math.acos(np.clip((R @ up_in_frame)[2], -1, 1))) < 1.0
    assert level_rotation(np.full((2, 3), np.nan)) is None


def test_bad_tables_are_input_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError):
        read_tree_table(empty)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "TreeManagerState_0.csv").write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="location_x"):
        read_tree_table(bad)
    with pytest.raises(InputError):
        read_tree_table(tmp_path / "missing")
    short = tmp_path / "short"
    write_layout(short, stand(50, 60.0, seed=1), frame_poses(3, seed=1), seed=1)
    (short / "trajectory.txt").write_text(tum_lines(frame_poses(1, seed=1)))
    with pytest.raises(InputError, match="poses"):
        read_tree_table(short)


def test_table_as_map_and_as_queries(tmp_path, world):
    """Session A's tables give the map, session B's tilted frames are localized in it (CLI)."""
    from typer.testing import CliRunner

    from forestslam.cli.main import app

    map_root = write_layout(tmp_path / "a", world, frame_poses(12, seed=7), seed=8)
    query_poses = frame_poses(4, seed=9)
    query_root = write_layout(tmp_path / "b", world, query_poses, seed=10)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["localize", str(query_root), "--map", str(map_root), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "localization.json").read_text())
    assert len(doc["queries"]) == 4
    for q, T in zip(doc["queries"], query_poses, strict=True):
        assert q["accepted"] and q["stage"] == "star"
        assert math.hypot(q["x"] - T[0, 3], q["y"] - T[1, 3]) < 0.2
    # The common job skeleton: run.yaml records the outcome, the lock is released.
    from forestslam.job import run_status

    assert run_status(out) == ("complete", None)
    # The window (--start, --max-scans) over the frames.
    args = ["--out", str(out), "--start", "1", "--max-scans", "2", "--no-progress"]
    result = CliRunner().invoke(app, ["localize", str(query_root), "--map", str(map_root), *args])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "localization.json").read_text())
    assert [q["scan"] for q in doc["queries"]] == [1, 2]


def test_a_truncated_packed_table_is_one_line_naming_the_row(tmp_path):
    """A copy cut off mid-row: numpy's multi-line message becomes one line (the CLI shows one)."""
    path = tmp_path / "trees.csv"
    path.write_text("frame,location_x,location_y,location_z\n0,1,2,3\n0,4,5,6\n1,7")
    with pytest.raises(InputError, match=r"malformed tree table") as caught:
        read_tree_table(path)
    assert "\n" not in str(caught.value) and "Line #4 (got 2 columns" in str(caught.value)


def test_rows_without_location_are_counted_and_negative_frames_refused(tmp_path, caplog):
    path = tmp_path / "trees.csv"
    path.write_text("frame,location_x,location_y,location_z\n0,1,2,3\n0,nan,5,6\n1,7,8,9\n")
    table = read_tree_table(path)
    assert len(table.xyz) == 2 and "1 rows without a finite location ignored" in caplog.text
    path.write_text("frame,location_x,location_y,location_z\n-1,1,2,3\n0,4,5,6\n")
    (tmp_path / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match="negative frame index"):  # poses[-1]: the last pose
        read_tree_table(path)
