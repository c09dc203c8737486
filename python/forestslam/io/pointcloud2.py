"""sensor_msgs/PointCloud2 <-> Scan with numpy, from the message's own field list.

Decoding honours any field order, offsets, padding, `point_step`, `row_step` (row padding),
byte order and datatypes INT8..FLOAT64; organized clouds (height > 1) are flattened row-major
and their NaN holes dropped (see forestslam.io.fields for accepted field names).

Writing uses the layout of the ROS Velodyne driver's `PointcloudXYZIRT` container: x, y, z,
intensity float32 at offsets 0, 4, 8, 12, ring uint16 at 16, time float32 at 18 (seconds
relative to header.stamp), packed without padding: point_step 22, height 1, row_step 22 * N.
"""

from __future__ import annotations

import numpy as np

from forestslam.errors import InputError
from forestslam.io.fields import scan_from_structured
from forestslam.io.scan import Scan

# sensor_msgs/PointField datatype constants -> numpy type codes (without byte order).
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
DATATYPE_NAMES = {
    1: "int8",
    2: "uint8",
    3: "int16",
    4: "uint16",
    5: "int32",
    6: "uint32",
    7: "float32",
    8: "float64",
}

VELODYNE_FIELDS = (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7))
VELODYNE_FIELDS += (("ring", 16, 4), ("time", 18, 7))
VELODYNE_POINT_STEP = 22
VELODYNE_DTYPE = np.dtype(
    {
        "names": [f[0] for f in VELODYNE_FIELDS],
        "formats": [f"<{DATATYPES[f[2]]}" for f in VELODYNE_FIELDS],
        "offsets": [f[1] for f in VELODYNE_FIELDS],
        "itemsize": VELODYNE_POINT_STEP,
    }
)


def fields_dtype(fields, point_step: int, bigendian: bool, where: str) -> np.dtype:
    """PointField list (objects with name, offset, datatype, count) -> structured dtype."""
    order = ">" if bigendian else "<"
    names, formats, offsets = [], [], []
    for field in fields:
        name = str(field.name)
        if not name or name in names:  # unnamed or repeated padding fields
            continue
        code = DATATYPES.get(int(field.datatype))
        if code is None:
            raise InputError(f"{where}: field {name!r} has unknown datatype {field.datatype}")
        count = max(int(field.count), 1)
        fmt = np.dtype(order + code) if count == 1 else np.dtype((order + code, (count,)))
        if field.offset + fmt.itemsize > point_step:
            raise InputError(
                f"{where}: field {name!r} (offset {field.offset}) overruns point_step {point_step}"
            )
        names.append(name)
        formats.append(fmt)
        offsets.append(int(field.offset))
    return np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )


def describe_fields(fields) -> dict[str, str]:
    """PointField list -> {name: datatype name (with [count] when count > 1)}."""
    out = {}
    for f in fields:
        name = DATATYPE_NAMES.get(int(f.datatype), f"unknown({f.datatype})")
        out[str(f.name)] = name if int(f.count) <= 1 else f"{name}[{int(f.count)}]"
    return out


def structured_points(msg, where: str = "PointCloud2") -> np.ndarray:
    """The message's points as a (height, width) structured array (a view, no copy)."""
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    dtype = fields_dtype(msg.fields, point_step, bool(msg.is_bigendian), where)
    if height == 0 or width == 0:
        return np.zeros((0, 0), dtype=dtype)
    if point_step <= 0 or row_step < width * point_step:
        raise InputError(
            f"{where}: inconsistent layout (width {width}, point_step {point_step}, "
            f"row_step {row_step})"
        )
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    needed = (height - 1) * row_step + width * point_step
    if data.size < needed:
        raise InputError(f"{where}: data has {data.size} bytes, layout needs {needed}")
    return np.ndarray(
        shape=(height, width), dtype=dtype, buffer=data, strides=(row_step, point_step)
    )


def stamp_seconds(header) -> float:
    stamp = header.stamp
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _core_mask():
    try:
        from forestslam import _core
    except ImportError:
        return None
    return getattr(_core, "real_point_indices", None)


_REAL_POINT_INDICES = _core_mask()


def real_point_indices(msg, arr: np.ndarray) -> np.ndarray | None:
    """Indices of finite, non-origin points computed in C++ in one pass over the buffer, or
    None (then numpy does it) when x, y, z are not all float32 or all float64."""
    if _REAL_POINT_INDICES is None or arr.size == 0:
        return None
    by_name: dict = {}
    for f in msg.fields:  # the first field of a name wins, as in fields_dtype
        by_name.setdefault(str(f.name).lower(), f)
    xyz = [by_name.get(c) for c in "xyz"]
    if any(f is None for f in xyz) or {int(f.datatype) for f in xyz} not in ({7}, {8}):
        return None
    return _REAL_POINT_INDICES(
        np.asarray(msg.data, dtype=np.uint8).reshape(-1),
        int(msg.height),
        int(msg.width),
        int(msg.point_step),
        int(msg.row_step),
        [int(f.offset) for f in xyz],
        4 if int(xyz[0].datatype) == 7 else 8,
        bool(msg.is_bigendian),
    )


def decode_pointcloud2(msg, where: str = "PointCloud2") -> Scan:
    """A deserialized PointCloud2 (rosbags message object) -> Scan with finite points."""
    arr = structured_points(msg, where)
    keep = real_point_indices(msg, arr)
    return scan_from_structured(arr, stamp_seconds(msg.header), where, keep)


def velodyne_array(scan: Scan) -> np.ndarray:
    """Scan -> packed Velodyne-layout structured array (missing fields written as 0)."""
    n = len(scan)
    arr = np.zeros(n, dtype=VELODYNE_DTYPE)
    if n:
        arr["x"], arr["y"], arr["z"] = scan.points[:, 0], scan.points[:, 1], scan.points[:, 2]
        if scan.intensity is not None:
            arr["intensity"] = scan.intensity
        if scan.ring is not None:
            arr["ring"] = scan.ring
        if scan.time is not None:
            arr["time"] = scan.time
    return arr
