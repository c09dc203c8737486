"""The C++ program forestslam_odometry (issue 18): a folder of PCD or KITTI .bin scans -> a TUM
trajectory, without Python; the same poses as the Python Odometry on the same scans."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

N_SCANS = 12


def _program() -> Path:
    """The program of this checkout's build (`make test` builds build/py with the C++ tests and
    installs the package from it), or next to a `_core` loaded from a build tree (dev.sh)."""
    core = pytest.importorskip("forestslam._core")
    app = Path("cpp") / "apps" / "forestslam_odometry"
    candidates = [
        Path(__file__).resolve().parents[1] / "build" / "py" / app,
        Path(core.__file__).resolve().parents[2] / app,
    ]
    for path in candidates:
        if path.is_file():
            return path
    pytest.skip(f"forestslam_odometry not built (looked at {', '.join(map(str, candidates))})")


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(_program()), *map(str, args)], capture_output=True, text=True, timeout=120
    )


@pytest.fixture(scope="module")
def sample_scans():
    pytest.importorskip("forestslam._core")
    from forestslam.sim.scenarios import load_scenario
    from forestslam.sim.simulate import scan_at
    from forestslam.sim.world import build_world

    world = build_world(load_scenario("sample", max_scans=N_SCANS))
    return world, [scan_at(world, k) for k in range(N_SCANS)]


def _write_pcd_folder(folder: Path, scans, named_by_stamp: bool = True) -> None:
    from forestslam.io.pcd import write_pcd

    folder.mkdir()
    for k, scan in enumerate(scans):
        arr = np.zeros(
            len(scan.points),
            dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4"), ("ring", "u2"),
                   ("time", "f8")],
        )  # fmt: skip
        for i, axis in enumerate("xyz"):
            arr[axis] = scan.points[:, i]
        arr["intensity"], arr["ring"], arr["time"] = scan.intensity, scan.ring, scan.time
        name = f"{scan.stamp:.6f}" if named_by_stamp else f"scan_{k:04d}"
        write_pcd(folder / f"{name}.pcd", arr)


def test_program_matches_python_odometry(sample_scans, tmp_path):
    from forestslam.io import Scan, read_tum
    from forestslam.odometry import Odometry

    world, scans = sample_scans
    _write_pcd_folder(tmp_path / "scans", scans)
    out = tmp_path / "trajectory.tum"
    proc = _run(tmp_path / "scans", "--sensor", world.profile.name, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert f"{N_SCANS} scans" in proc.stderr
    stamps, poses = read_tum(out)
    np.testing.assert_allclose(stamps, [s.stamp for s in scans], atol=1e-6)
    odo = Odometry(world.profile)
    # The PCD files hold float32 coordinates: the Python side gets the same.
    f32 = [
        Scan(s.stamp, s.points.astype(np.float32).astype(np.float64), s.intensity, s.ring, s.time)
        for s in scans
    ]
    ref = np.stack([odo.step(s).T_world_sensor for s in f32])
    np.testing.assert_allclose(poses[:, :3, 3], ref[:, :3, 3], atol=2e-3)
    assert np.linalg.norm(poses[-1, :3, 3]) > 0.5  # it moved


def test_program_stamps_by_order_and_kitti_bins(sample_scans, tmp_path):
    from forestslam.io import read_tum

    world, scans = sample_scans
    folder = tmp_path / "kitti"
    folder.mkdir()
    for k, scan in enumerate(scans[:3]):
        data = np.column_stack([scan.points, scan.intensity]).astype("<f4")
        (folder / f"seq_{k:02d}.bin").write_bytes(data.tobytes())
    (folder / "seq_03.bin").write_bytes(b"\0" * 17)  # not whole float32 x y z i records
    out = tmp_path / "t.tum"
    proc = _run(folder, "--sensor", "vlp16", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "seq_03.bin" in proc.stderr and "multiple of 16" in proc.stderr
    stamps, _ = read_tum(out)
    np.testing.assert_allclose(stamps, [0.0, 0.1, 0.2])  # file order at the profile's 10 Hz


@pytest.mark.parametrize(
    "args, message",
    [
        (["nosuchdir", "--sensor", "vlp16", "--out", "x.tum"], "not a folder"),
        (["{tmp}", "--sensor", "banana", "--out", "x.tum"], "unknown sensor 'banana'"),
        (["{tmp}", "--sensor", "vlp16"], "required"),
        (["{tmp}", "--sensor", "{tmp}/fast.yaml", "--out", "x.tum"], "rate_hz must be <= 100"),
    ],
)
def test_program_errors_are_one_line(tmp_path, args, message):
    (tmp_path / "0.0.bin").write_bytes(np.zeros((4, 4), "<f4").tobytes())
    vlp16 = Path(__file__).parents[1] / "python/forestslam/sensors/profiles/vlp16.yaml"
    (tmp_path / "fast.yaml").write_text(vlp16.read_text().replace("rate_hz: 10.0", "rate_hz: 1e5"))
    proc = _run(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert proc.returncode == 2
    assert message in proc.stderr.splitlines()[0]


def test_a_file_that_is_not_a_pcd_is_skipped_not_a_crash(sample_scans, tmp_path):
    """PCL's reader crashed (SIGSEGV) on a text file named .pcd; the program skips it."""
    folder = tmp_path / "scans"
    _write_pcd_folder(folder, sample_scans[1][:3])
    (folder / "9999999999.0.pcd").write_text("junk\n")
    (folder / "notes.txt").write_text("not a scan\n")
    proc = _run(folder, "--sensor", "vlp16", "--out", tmp_path / "t.tum")
    assert proc.returncode == 0, proc.stderr
    assert "9999999999.0.pcd: not a PCD file" in proc.stderr and "1 unreadable" in proc.stderr
    assert len((tmp_path / "t.tum").read_text().splitlines()) == 3
    only_junk = tmp_path / "junk"
    only_junk.mkdir()
    (only_junk / "1.pcd").write_text("junk\n")
    proc = _run(only_junk, "--sensor", "vlp16", "--out", tmp_path / "u.tum")
    assert proc.returncode == 1 and "no readable scan" in proc.stderr.splitlines()[-1]
