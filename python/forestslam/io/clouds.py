"""Single point-cloud files: one registry of readers by suffix, and the matching writers.

Readers (suffix -> structured points): .pcd, .ply, .las/.laz (laspy; GPS time becomes per-point
time relative to its minimum, which is the stamp; classification is kept when set, and extra
dimensions such as Ring; `read_cloud_array` gives them all, `read_cloud` the Scan fields),
KITTI .bin (float32 x, y, z, intensity), .npy ((N,3) x,y,z, (N,4) x,y,z,intensity, or a
structured array with named fields).
"""

from __future__ import annotations

import errno
import logging
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import column_bounds
from forestslam.io.atomic import atomic_write
from forestslam.io.fields import scan_from_structured
from forestslam.io.scan import Scan

log = logging.getLogger(__name__)

# A reader returns the points as a structured array and the stamp when the file has one.
CloudReader = Callable[[Path], tuple[np.ndarray, float | None]]


def _xyz_array(values: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    out = np.zeros(len(values), dtype=[(n, values.dtype) for n in names])
    for k, name in enumerate(names):
        out[name] = values[:, k]
    return out


def _read_pcd(path: Path) -> tuple[np.ndarray, float | None]:
    from forestslam.io.pcd import read_pcd

    return read_pcd(path), None


def _read_ply(path: Path) -> tuple[np.ndarray, float | None]:
    from forestslam.io.ply import read_ply

    return read_ply(path), None


def _read_las(path: Path) -> tuple[np.ndarray, float | None]:
    import laspy

    try:
        las = laspy.read(path)
    except Exception as exc:  # noqa: BLE001 - laspy raises many types for bad files
        raise InputError(f"{path}: cannot read LAS/LAZ ({exc})") from None
    n = len(las.points)
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8"), ("intensity", "f4")]
    extra = [(d.name, d.dtype) for d in las.point_format.extra_dimensions if d.num_elements == 1]
    gps = (
        np.asarray(las.gps_time, dtype=np.float64)
        if "gps_time" in las.point_format.dimension_names
        else None
    )
    if gps is not None and not np.any(gps):
        gps = None
    if gps is not None:
        fields.append(("time", "f8"))
    classes = np.asarray(las.classification, dtype=np.uint8)
    if classes.any():  # ground (2), vegetation ... for checks against classified clouds
        fields.append(("classification", "u1"))
    names = {f[0] for f in fields}
    fields += [(name, dt) for name, dt in extra if name.lower() not in names]
    out = np.zeros(n, dtype=fields)
    out["x"], out["y"], out["z"] = las.x, las.y, las.z
    out["intensity"] = las.intensity
    stamp = None
    if gps is not None:
        stamp = float(gps.min()) if n else 0.0
        out["time"] = gps - stamp
    if classes.any():
        out["classification"] = classes
    for name, _dt in fields[4 + (gps is not None) + bool(classes.any()) :]:
        out[name] = las[name]
    return out, stamp


def _read_bin(path: Path) -> tuple[np.ndarray, float | None]:
    size = path.stat().st_size
    if size % 16:  # np.fromfile would drop a partial float silently
        raise InputError(
            f"{path}: KITTI .bin size {size} bytes is not a multiple of 16 "
            "(4 float32 per point: x, y, z, intensity); the file is cut or not KITTI"
        )
    raw = np.fromfile(path, dtype="<f4")
    return _xyz_array(raw.reshape(-1, 4), ("x", "y", "z", "intensity")), None


def _read_npy(path: Path) -> tuple[np.ndarray, float | None]:
    try:
        arr = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise InputError(f"{path}: not a numpy .npy array ({exc})") from None
    if arr.dtype.names:
        return arr.reshape(-1), None
    if arr.ndim == 2 and arr.shape[1] in (3, 4):
        return _xyz_array(arr, ("x", "y", "z", "intensity")[: arr.shape[1]]), None
    raise InputError(f"{path}: .npy must be (N,3), (N,4) or structured, not {arr.shape}")


CLOUD_READERS: dict[str, CloudReader] = {
    ".pcd": _read_pcd,
    ".ply": _read_ply,
    ".las": _read_las,
    ".laz": _read_las,
    ".bin": _read_bin,
    ".npy": _read_npy,
}


def why_missing(path: Path) -> str:
    """Why an input path does not exist: a symbolic link loop, a dangling link, or absent."""
    try:
        path.resolve(strict=True)
    except RuntimeError:  # Python < 3.13 reports a loop so
        return "symbolic link loop"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "symbolic link loop (or too many levels of links)"
        if path.is_symlink():
            return f"dangling symbolic link (to {os.readlink(path)}, which does not exist)"
    return "file not found"


def read_cloud_array(path: str | Path) -> tuple[np.ndarray, float | None]:
    """One cloud file -> (structured points, stamp or None)."""
    path = Path(path)
    reader = CLOUD_READERS.get(path.suffix.lower())
    if reader is None:
        raise InputError(
            f"{path}: unsupported cloud file type {path.suffix!r} "
            f"(supported: {', '.join(sorted(CLOUD_READERS))})"
        )
    if not path.exists():
        raise InputError(f"{path}: {why_missing(path)}")
    if not path.is_file():
        raise InputError(f"{path}: not a file")
    try:
        return reader(path)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - parsers of damaged files raise anything
        raise InputError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None


def read_cloud(path: str | Path, stamp: float | None = None) -> Scan:
    """One .las/.laz/.pcd/.ply/.npy/.bin file -> Scan (finite points; stamp from the file's
    per-point times when present, else `stamp`, else 0)."""
    arr, file_stamp = read_cloud_array(path)
    return scan_from_structured(arr, file_stamp if file_stamp is not None else stamp, str(path))


def _scan_array(points: np.ndarray, intensity: np.ndarray | None, dtype: str) -> np.ndarray:
    fields = [("x", dtype), ("y", dtype), ("z", dtype)]
    if intensity is not None:
        fields.append(("intensity", "f4"))
    out = np.zeros(len(points), dtype=fields)
    out["x"], out["y"], out["z"] = points[:, 0], points[:, 1], points[:, 2]
    if intensity is not None:
        out["intensity"] = intensity
    return out


def _write_las(path: Path, points: np.ndarray, intensity: np.ndarray | None) -> None:
    import laspy

    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        log.warning("%s: LAS has no NaN: %d non-finite points left out", path, (~finite).sum())
        points = points[finite]
        intensity = None if intensity is None else intensity[finite]
    lo, hi = column_bounds(points)
    low = np.floor(lo)
    extent = float((hi - low).max()) if len(points) else 0.0
    # 0.1 mm resolution while the int32 range allows it, coarser (by 10x steps) beyond 200 km.
    scale = 1e-4 * 10.0 ** max(0, int(np.ceil(np.log10(max(extent, 1.0) / 2e5))))
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.array([scale, scale, scale])
    header.offsets = low
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    if intensity is not None:
        las.intensity = np.clip(np.rint(intensity), 0, 65535).astype(np.uint16)
    compress = path.suffix.lower() == ".laz"
    atomic_write(path, lambda f: las.write(f, do_compress=compress), "wb")


def write_cloud(path: str | Path, points: np.ndarray, intensity: np.ndarray | None = None) -> None:
    """Write points (N,3) [and intensity (N,)] atomically; the suffix chooses the format.

    .laz/.las: LAS 1.2 point format 0, 0.1 mm resolution (coarser for extents over 200 km),
    intensity rounded to uint16; non-finite points are left out with a warning (LAS has no NaN).
    .ply: binary little endian, x,y,z double, intensity float.  .pcd: binary, x,y,z float64.
    .npy: (N,3) float64, or (N,4) with intensity as the 4th column.  .bin: KITTI float32 x4.
    """
    path = Path(path)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if intensity is not None:
        intensity = np.asarray(intensity, dtype=np.float32).reshape(-1)
        if len(intensity) != len(points):
            raise InputError(f"{path}: {len(intensity)} intensities for {len(points)} points")
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz"):
        _write_las(path, points, intensity)
    elif suffix == ".ply":
        from forestslam.io.ply import write_ply

        write_ply(path, _scan_array(points, intensity, "f8"))
    elif suffix == ".pcd":
        from forestslam.io.pcd import write_pcd

        write_pcd(path, _scan_array(points, intensity, "f8"))
    elif suffix == ".npy":
        table = points if intensity is None else np.column_stack([points, intensity])
        atomic_write(path, lambda f: np.save(f, table), "wb")
    elif suffix == ".bin":
        table = np.zeros((len(points), 4), dtype="<f4")
        table[:, :3] = points
        if intensity is not None:
            table[:, 3] = intensity
        atomic_write(path, lambda f: f.write(table.tobytes()), "wb")
    else:
        raise InputError(
            f"{path}: unsupported output type {path.suffix!r} (.laz .las .ply .pcd .npy .bin)"
        )
