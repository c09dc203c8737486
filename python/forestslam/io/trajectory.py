"""Trajectories: TUM (`timestamp tx ty tz qx qy qz qw`, evo-compatible) and KITTI pose files."""

from __future__ import annotations

import warnings
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
    return [" ".join(f"{v:.9f}" for v in row) for row in rows]


def write_tum(path: str | Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """Write stamps (N,) and poses (N,4,4) as a TUM file, atomically."""
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} stamps for {len(poses)} poses")
    lines = poses_to_tum_lines(stamps, poses)
    atomic_write_text(path, "".join(line + "\n" for line in lines))


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file -> stamps (N,), poses (N,4,4). Comment lines (#) are skipped."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: trajectory file not found")
    try:
        with warnings.catch_warnings():  # an empty file is an empty trajectory
            warnings.simplefilter("ignore", UserWarning)
            data = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path}: not a TUM trajectory ({exc})") from None
    if data.size == 0:
        return np.zeros(0), np.zeros((0, 4, 4))
    if data.shape[1] != 8:
        raise InputError(f"{path}: TUM lines need 8 columns, found {data.shape[1]}")
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
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: pose file not found")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            data = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path}: not a KITTI pose file ({exc})") from None
    if data.size == 0:
        return np.zeros((0, 4, 4))
    if data.shape[1] != 12:
        raise InputError(f"{path}: KITTI pose lines need 12 numbers, found {data.shape[1]}")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :4] = data.reshape(-1, 3, 4)
    return poses
