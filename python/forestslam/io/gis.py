"""Maps for GIS and point-cloud tools: `map.laz` (CloudCompare, lidR, QGIS) and `trees.gpkg`.

- map.laz: LAS 1.4, point format 6, 1 mm scale with offsets at the cloud's lower corner (so UTM
  coordinates keep millimetres), classification 2 on ground and 1 elsewhere, a `tree_id`
  extra-bytes dimension (the trees.csv id on stem points, 0 elsewhere), GPS time per point and
  the CRS as a WKT VLR when the run has one. Written by laspy.
- trees.gpkg: a GeoPackage point layer `trees` (id, dbh_m, dbh_std_m, observations, status,
  height_m when known) with the CRS as its srs. Written by pyogrio (GDAL).
Both are written beside the target and renamed into place, so a crash never leaves half a file.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import column_bounds

GROUND, UNCLASSIFIED = 2, 1  # ASPRS classes
SCALE_M = 0.001
GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06 in Unix seconds
GPS_LEAP_S = 18.0  # GPS - UTC since 2017-01-01


@contextmanager
def _atomic_target(path: Path):
    """A temporary path beside `path`, renamed onto it when the block succeeds."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    os.unlink(tmp)  # the writers create the file themselves
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_map_laz(
    path: str | Path,
    points: np.ndarray,
    classification: np.ndarray,
    tree_id: np.ndarray,
    gps_time: np.ndarray,
    crs=None,
) -> None:
    """Write the map cloud: `points` (N,3) float64 in the output frame, `classification` (N,)
    ASPRS classes, `tree_id` (N,) (0: not a stem), `gps_time` (N,) the scans' stamps; `crs` a
    pyproj CRS or None. Stamps on the Unix clock (a recording's) become adjusted standard GPS
    time (the header says so); others (a simulation's seconds) are written as they are."""
    import laspy

    path = Path(path)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    for name, a in (
        ("classification", classification),
        ("tree_id", tree_id),
        ("gps_time", gps_time),
    ):
        if len(a) != n:
            raise InputError(f"{path}: {name} has {len(a)} values for {n} points")
    if n and not np.isfinite(pts).all():
        raise InputError(f"{path}: the map holds non-finite coordinates")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="tree_id", type=np.uint32))
    header.scales = np.full(3, SCALE_M)
    header.offsets = np.floor(column_bounds(pts)[0]) if n else np.zeros(3)
    if crs is not None:
        header.add_crs(crs)
    times, adjusted = las_gps_time(np.asarray(gps_time, dtype=np.float64))
    header.global_encoding.gps_time_type = adjusted
    # The record sized once: filled field by field, an empty one is regrown per field.
    las = laspy.LasData(header, laspy.ScaleAwarePointRecord.zeros(n, header=header))
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = np.asarray(classification, dtype=np.uint8)
    las.tree_id = np.asarray(tree_id, dtype=np.uint32)
    las.gps_time = times
    with _atomic_target(path) as tmp:
        las.write(str(tmp))


def las_gps_time(stamps: np.ndarray) -> tuple[np.ndarray, bool]:
    """LAS GPS time of stamps: adjusted standard GPS time (GPS seconds - 1e9) when every stamp is
    a Unix time after 2001, else the stamps unchanged; and whether they were converted."""
    if len(stamps) and np.all(stamps > 1e9):
        return stamps - GPS_EPOCH_UNIX_S + GPS_LEAP_S - 1e9, True
    return stamps, False


def write_trees_gpkg(path: str | Path, table: dict[str, np.ndarray], crs=None) -> None:
    """The tree map as a GeoPackage point layer `trees`: geometry (x, y) in the output frame and
    every other column of `table` (id, dbh_m, dbh_std_m, observations, status, height_m, z ...)
    as a field; `crs` a pyproj CRS or None (then the layer has no srs)."""
    from pyogrio.raw import write

    path = Path(path)
    if "x" not in table or "y" not in table:
        raise InputError(f"{path}: trees need x and y columns")
    x = np.asarray(table["x"], dtype=np.float64)
    y = np.asarray(table["y"], dtype=np.float64)
    names = [k for k in table if k not in ("x", "y")]
    data = [_field(np.asarray(table[k])) for k in names]
    with _atomic_target(path) as tmp, warnings.catch_warnings():
        # a run without a CRS writes a layer without one on purpose (its local frame)
        warnings.filterwarnings("ignore", message="'crs' was not provided")
        write(
            str(tmp),
            geometry=_wkb_points(x, y),
            field_data=data,
            fields=names,
            layer="trees",
            driver="GPKG",
            geometry_type="Point",
            crs=None if crs is None else crs.to_wkt(),
        )


def _field(values: np.ndarray) -> np.ndarray:
    if values.dtype.kind in "iu":
        return values.astype(np.int64)
    if values.dtype.kind in "fb":
        return values.astype(np.float64)
    return values.astype(object)


def _wkb_points(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Little-endian WKB Points, one per tree (an object array of bytes, as pyogrio takes)."""
    rec = np.zeros(len(x), dtype=[("order", "u1"), ("kind", "<u4"), ("x", "<f8"), ("y", "<f8")])
    rec["order"], rec["kind"], rec["x"], rec["y"] = 1, 1, x, y
    raw = rec.tobytes()
    size = rec.dtype.itemsize
    return np.array([raw[i * size : (i + 1) * size] for i in range(len(x))], dtype=object)
