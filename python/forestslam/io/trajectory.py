"""Trajectories: TUM (`timestamp tx ty tz qx qy qz qw`, evo-compatible) and KITTI pose files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from forestslam.errors import InputError
from forestslam.io.atomic import atomic_write_text


def poses_to_tum_lines(stamps: np.ndarray, poses: np.ndarray) -> list[str]:
    """stamps (N,), poses (N,4,4) -> TUM lines."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(poses) == 0:
        return []
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # x, y, z, w
    rows = np.column_stack([np.asarray(stamps, dtype=np.float64), poses[:, :3, 3], quat])
    line = " ".join(["%.9f"] * rows.shape[1])  # the text of f"{v:.9f}", one format per row
    return [line % tuple(row) for row in rows.tolist()]


def write_tum(path: str | Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """Write stamps (N,) and poses (N,4,4) as a TUM file, atomically."""
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} stamps for {len(poses)} poses")
    lines = poses_to_tum_lines(stamps, poses)
    atomic_write_text(path, "".join(line + "\n" for line in lines))


def _rows(path: Path, columns: int, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """The finite numbers of a text pose file, (N, columns), and each row's line number (N,).
    Blank lines and # comments are skipped; any other bad line is an InputError naming it."""
    if not path.is_file():
        raise InputError(f"{path}: {kind} file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError) as exc:
        raise InputError(f"{path}: not a {kind} text file ({exc})") from None
    rows, numbers = [], []
    for n, line in enumerate(text.splitlines(), start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) != columns:
            raise InputError(
                f"{path} line {n}: {kind} lines need {columns} numbers, found {len(fields)}"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise InputError(f"{path} line {n}: not a number in {line.strip()[:80]!r}") from None
        if not np.isfinite(values).all():
            raise InputError(f"{path} line {n}: non-finite value in {line.strip()[:80]!r}")
        rows.append(values)
        numbers.append(n)
    return np.asarray(rows, dtype=np.float64).reshape(-1, columns), np.asarray(numbers)


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file -> stamps (N,), poses (N,4,4). Comment lines (#) are skipped; a line
    that is not 8 finite numbers, or a quaternion of (almost) zero norm, is an InputError
    naming the line."""
    path = Path(path)
    data, lines = _rows(path, 8, "TUM trajectory")
    if len(data) == 0:
        return np.zeros(0), np.zeros((0, 4, 4))
    norm = np.linalg.norm(data[:, 4:8], axis=1)
    bad = np.flatnonzero(norm < 1e-6)
    if len(bad):
        raise InputError(
            f"{path} line {lines[bad[0]]}: quaternion (qx qy qz qw) of norm "
            f"{norm[bad[0]]:.3g} is no rotation ({len(bad)} such lines)"
        )
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(data[:, 4:8]).as_matrix()
    poses[:, :3, 3] = data[:, 1:4]
    return data[:, 0], poses


def write_kitti(path: str | Path, poses: np.ndarray) -> None:
    """KITTI poses: the top 3x4 of each pose, row-major, one line each."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    text = "".join(" ".join(f"{v:.9e}" for v in p[:3].ravel()) + "\n" for p in poses)
    atomic_write_text(path, text)


def read_kitti(path: str | Path) -> np.ndarray:
    """Read KITTI poses -> (N,4,4); a line that is not 12 finite numbers is an InputError
    naming the line."""
    data, _ = _rows(Path(path), 12, "KITTI pose")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :4] = data.reshape(-1, 3, 4)
    return poses
