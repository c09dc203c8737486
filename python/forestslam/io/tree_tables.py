"""Per-frame tree tables of other tree mappers (RealtimeTrees, as used by TreeLoc/TreeLoc++).

Two layouts are read:

- a directory of ``TreeManagerState_<k>.csv`` files (one per frame k: the local tree map around
  pose k, in the frame of pose k) plus ``trajectory.txt`` (TUM lines ``stamp x y z qx qy qz qw``,
  row k = pose of frame k, optional);
- a packed table ``trees.csv[.gz]`` with the same columns plus ``frame`` (a directory holding it
  and ``trajectory.tum`` / ``trajectory.txt``, or the file itself).

Columns used: ``location_x/y/z`` (m), ``dbh`` (m, empty when not fitted; ``dbh_approximation``
then), ``reconstructed``, ``score`` and the stem axis frame ``axis_00..axis_22``, whose third
column (``axis_02, axis_12, axis_22``) is the stem direction (checked on the Wild-Places tables:
within about 1 deg of the reference gravity, the third row is 13-20 deg off).
"""

from __future__ import annotations

import gzip
import io
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from forestslam.errors import InputError

log = logging.getLogger(__name__)
STATE_PATTERN = re.compile(r"TreeManagerState_(\d+)\.csv$")
REQUIRED = ("location_x", "location_y", "location_z")
AXIS = ("axis_02", "axis_12", "axis_22")  # the stem direction: third column of the axis frame


@dataclass(frozen=True)
class TreeTable:
    """Trees of every frame, flat: row i is a tree of frame ``frame[i]``, in that frame."""

    frame: np.ndarray  # (N,) int64 frame index k
    xyz: np.ndarray  # (N,3) tree location in the frame of pose k (m)
    dbh_m: np.ndarray  # (N,) NaN when neither dbh nor dbh_approximation is given
    axis: np.ndarray  # (N,3) unit stem direction in the frame (NaN when absent)
    reconstructed: np.ndarray  # (N,) bool
    poses: np.ndarray | None  # (F,4,4) T_world_frame per frame index (row k), or None
    stamps: np.ndarray | None  # (F,)

    @property
    def frames(self) -> np.ndarray:
        """Frame indices that hold at least one tree, ascending."""
        return np.unique(self.frame)

    def rows(self, k: int) -> np.ndarray:
        """Row indices of frame k."""
        lo, hi = np.searchsorted(self.frame, [k, k + 1])
        return np.arange(lo, hi)


def is_tree_table(path: str | Path) -> bool:
    """True for a packed table file or a directory in either layout."""
    path = Path(path)
    if path.is_file():
        return path.name.endswith((".csv", ".csv.gz")) and _is_packed_header(path)
    if not path.is_dir():
        return False
    return _packed_file(path) is not None or any(_state_files(path))


def read_tree_table(path: str | Path) -> TreeTable:
    """Read a tree-table directory (either layout) or a packed table file."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: tree table not found")
    if path.is_file():
        columns = _read_csv(path)
        trajectory = _trajectory_file(path.parent)
    else:
        packed = _packed_file(path)
        if packed is not None:
            columns = _read_csv(packed)
        else:
            columns = _read_states(path)
        trajectory = _trajectory_file(path)
    if "frame" not in columns:
        raise InputError(f"{path}: packed tree table without a 'frame' column")
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        raise InputError(f"{path}: tree table misses columns {missing}")
    return _table(columns, trajectory, path)


def _table(columns: dict[str, np.ndarray], trajectory: Path | None, where: Path) -> TreeTable:
    frame = columns["frame"]
    if not np.isfinite(frame).all() or (frame < 0).any():
        raise InputError(f"{where}: non-numeric or negative frame index")
    frame = frame.astype(np.int64)
    xyz = np.column_stack([columns[c] for c in REQUIRED])
    n = len(frame)
    dbh = columns.get("dbh", np.full(n, np.nan)).copy()
    approx = columns.get("dbh_approximation", np.full(n, np.nan))
    dbh[~np.isfinite(dbh)] = approx[~np.isfinite(dbh)]
    if all(c in columns for c in AXIS):
        axis = np.column_stack([columns[c] for c in AXIS])
        norm = np.linalg.norm(axis, axis=1, keepdims=True)
        axis = np.where(norm > 1e-9, axis / np.where(norm > 1e-9, norm, 1), np.nan)
    else:
        axis = np.full((n, 3), np.nan)
    recon = columns.get("reconstructed", np.ones(n))
    keep = np.isfinite(xyz).all(axis=1)
    if not keep.all():
        log.warning("%s: %d rows without a finite location ignored", where, (~keep).sum())
    order = np.argsort(frame[keep], kind="stable")
    stamps = poses = None
    if trajectory is not None:
        from forestslam.io import read_tum

        stamps, poses = read_tum(trajectory)
        if len(frame) and frame.max() >= len(poses):
            raise InputError(
                f"{trajectory}: {len(poses)} poses, but the tree table has frame {frame.max()}"
            )
    return TreeTable(
        frame=frame[keep][order],
        xyz=xyz[keep][order],
        dbh_m=dbh[keep][order],
        axis=axis[keep][order],
        reconstructed=(recon[keep][order] > 0.5),
        poses=poses,
        stamps=stamps,
    )


def level_rotation(axes: np.ndarray, min_axes: int = 3) -> np.ndarray | None:
    """(3,3) rotation R_level_frame that turns the frame's robust mean stem axis to +z (the
    smallest such rotation: heading kept). Stems lean a few degrees each way; their
    median direction is the vertical. None when fewer than ``min_axes`` axes are known."""
    a = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    a = a[np.isfinite(a).all(axis=1)]
    if len(a) < min_axes:
        return None
    a = a * np.where(a[:, 2:3] < 0, -1.0, 1.0)  # an axis has no sign: point it up
    up = np.median(a, axis=0)
    # One reweighting step: stems more than 15 deg off the median (leaning, wrong fits) out.
    close = a @ (up / np.linalg.norm(up)) > np.cos(np.radians(15))
    if close.sum() >= min_axes:
        up = np.mean(a[close], axis=0)
    up /= np.linalg.norm(up)
    return _rotation_between(up, np.array([0.0, 0.0, 1.0]))


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector a to unit vector b (Rodrigues)."""
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _state_files(root: Path):
    for p in root.iterdir():
        m = STATE_PATTERN.match(p.name)
        if m and p.is_file():
            yield int(m.group(1)), p


def _packed_file(root: Path) -> Path | None:
    for name in ("trees.csv.gz", "trees.csv"):
        if (root / name).is_file() and _is_packed_header(root / name):
            return root / name
    return None


def _trajectory_file(root: Path) -> Path | None:
    for name in ("trajectory.txt", "trajectory.tum"):
        if (root / name).is_file():
            return root / name
    return None


def _open_text(path: Path):
    return gzip.open(path, "rt") if path.name.endswith(".gz") else path.open()


def _is_packed_header(path: Path) -> bool:
    try:
        with _open_text(path) as f:
            header = f.readline()
    except (OSError, UnicodeDecodeError, EOFError):
        return False
    names = {n.strip() for n in header.split(",")}
    return "location_x" in names


def _parse(text: str, where: Path) -> dict[str, np.ndarray]:
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(f"{where}: empty tree table")
    names = [n.strip() for n in lines[0].split(",")]
    if len(lines) == 1:
        return {n: np.zeros(0) for n in names}
    try:
        data = np.genfromtxt(
            io.StringIO(text), delimiter=",", skip_header=1, dtype=np.float64, filling_values=np.nan
        )
    except ValueError as exc:
        reason = " ".join(str(exc).split())  # numpy's message spans lines: the CLI shows one
        raise InputError(f"{where}: malformed tree table ({reason})") from None
    data = data.reshape(-1, len(names))
    return {n: data[:, i] for i, n in enumerate(names)}


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with _open_text(path) as f:
        return _parse(f.read(), path)


def _read_states(root: Path) -> dict[str, np.ndarray]:
    files = sorted(_state_files(root))
    if not files:
        raise InputError(f"{root}: no TreeManagerState_<k>.csv files and no trees.csv[.gz]")
    parts = []
    for k, p in files:
        cols = _read_csv(p)
        n = len(next(iter(cols.values()))) if cols else 0
        cols["frame"] = np.full(n, float(k))
        parts.append(cols)
    names = set.intersection(*(set(c) for c in parts))
    return {n: np.concatenate([c[n] for c in parts]) for n in names}
