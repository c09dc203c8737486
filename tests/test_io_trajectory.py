"""Trajectories (TUM, KITTI) round-trip; atomic writes keep the old file when writing fails."""

from __future__ import annotations

import os
import re
import stat
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bags import sample_sequence

from forestslam.errors import InputError
from forestslam.io import read_kitti, read_tum, write_kitti, write_tum
from forestslam.io.atomic import atomic_write, atomic_write_text, remove_stale_temporaries


@pytest.fixture
def poses():
    rng = np.random.default_rng(6)
    n = 40
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 1.0, (n, 3))).as_matrix()
    out[:, :3, 3] = rng.uniform(-100, 100, (n, 3))
    return 1.7e9 + 0.1 * np.arange(n), out


def test_tum_round_trip(tmp_path, poses):
    stamps, T = poses
    write_tum(tmp_path / "t.tum", stamps, T)
    lines = (tmp_path / "t.tum").read_text().splitlines()
    assert len(lines) == 40 and len(lines[0].split()) == 8
    s, back = read_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(s, stamps, atol=1e-6)
    np.testing.assert_allclose(back, T, atol=1e-8)
    (tmp_path / "c.tum").write_text("# timestamp tx ty tz qx qy qz qw\n" + lines[0] + "\n")
    assert read_tum(tmp_path / "c.tum")[1].shape == (1, 4, 4)


def test_kitti_round_trip(tmp_path, poses):
    _, T = poses
    write_kitti(tmp_path / "k.txt", T)
    np.testing.assert_allclose(read_kitti(tmp_path / "k.txt"), T, atol=1e-8)


def test_trajectory_errors(tmp_path, poses):
    with pytest.raises(InputError, match="not found"):
        read_tum(tmp_path / "none.tum")
    (tmp_path / "bad.tum").write_text("1 2 3\n")
    with pytest.raises(InputError, match="8 numbers"):
        read_tum(tmp_path / "bad.tum")
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="12 numbers"):
        read_kitti(tmp_path / "bad.txt")
    with pytest.raises(ValueError, match="stamps"):
        write_tum(tmp_path / "x.tum", poses[0][:3], poses[1])


def test_atomic_write_keeps_old_file(tmp_path):
    path = tmp_path / "f.txt"
    atomic_write_text(path, "complete\n")

    def crash(handle):
        handle.write("half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        atomic_write(path, crash)
    assert path.read_text() == "complete\n"
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]  # no temporary left behind


def test_empty_and_garbage_trajectories(tmp_path):
    (tmp_path / "e.tum").write_text("")
    (tmp_path / "e.txt").write_text("")
    assert read_tum(tmp_path / "e.tum")[1].shape == (0, 4, 4)
    assert read_kitti(tmp_path / "e.txt").shape == (0, 4, 4)
    (tmp_path / "g.txt").write_text("a b c\n")
    with pytest.raises(InputError, match="g.txt"):
        read_kitti(tmp_path / "g.txt")
    with pytest.raises(InputError, match="g.txt"):
        read_tum(tmp_path / "g.txt")


def test_atomic_write_gives_ordinary_permissions(tmp_path):
    path = tmp_path / "shared.txt"
    atomic_write_text(path, "x\n")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_stale_temporaries_are_removed(tmp_path):
    (tmp_path / ".trees.csv.abc123.tmp").write_text("half")
    (tmp_path / "trees.csv").write_text("id\n")
    assert remove_stale_temporaries(tmp_path) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["trees.csv"]


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("0 0 0 0 0 0 0", "quaternion (qx qy qz qw) of norm 0"),
        ("nan nan nan nan nan nan nan", "non-finite value"),
        ("1 2 3 4 5 6 x", "not a number"),
        ("1 2 3", "need 8 numbers, found 4"),
    ],
)
def test_bad_line_of_a_simulated_trajectory_is_named(tmp_path, capsys, line, needle):
    """A zero quaternion made `evaluate` print a scipy traceback; NaN or junk gave a loadtxt
    message without the line."""
    truth = sample_sequence("bag").parent / "truth"
    lines = (truth / "trajectory.tum").read_text().splitlines()
    stamp = lines[6].split()[0]
    lines[6] = f"{stamp} {line}"
    run = tmp_path / "run"
    run.mkdir()
    (run / "trajectory.tum").write_text("# comment\n" + "\n".join(lines) + "\n")
    with pytest.raises(InputError, match=f"trajectory.tum line 8: .*{re.escape(needle)}"):
        read_tum(run / "trajectory.tum")

    from forestslam.cli.main import main

    capsys.readouterr()
    old = sys.argv
    sys.argv = ["forestslam", "evaluate", str(run), "--truth", str(truth)]
    try:
        with pytest.raises(SystemExit) as exit_info:
            main()
    finally:
        sys.argv = old
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 1 and len(err) == 1, err
    assert err[0].startswith("forestslam: error: ") and "line 8" in err[0] and needle in err[0]
