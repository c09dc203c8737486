"""PointCloud2 decoding from the message's own layout: padding, order, byte order, datatypes,
organized clouds with NaN holes and row padding, driver-specific time fields."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import pointcloud2
from forestslam.io.pointcloud2 import DATATYPES, decode_pointcloud2, structured_points

CODES = {v: k for k, v in DATATYPES.items()}


def make_msg(
    columns: dict[str, np.ndarray],
    layout: list[tuple[str, int, str]],
    point_step: int,
    *,
    height: int = 1,
    row_pad: int = 0,
    bigendian: bool = False,
    stamp: float = 100.25,
):
    """Pack columns by hand (not with our encoder) into a PointCloud2-like object."""
    n = len(next(iter(columns.values())))
    width = n // height
    order = ">" if bigendian else "<"
    row_step = width * point_step + row_pad
    buf = np.full(height * row_step, 0xAB, dtype=np.uint8)  # padding bytes are garbage
    rows = buf.reshape(height, row_step)
    for name, offset, code in layout:
        values = np.asarray(columns[name]).astype(order + code).reshape(height, width)
        size = np.dtype(code).itemsize
        raw = values.view(np.uint8).reshape(height, width, size)
        for b in range(size):
            rows[:, offset + b : width * point_step : point_step] = raw[:, :, b]
    fields = [
        SimpleNamespace(name=name, offset=offset, datatype=CODES[code], count=1)
        for name, offset, code in layout
    ]
    sec = int(stamp)
    header = SimpleNamespace(
        stamp=SimpleNamespace(sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
    )
    return SimpleNamespace(
        header=header,
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        data=buf,
        is_dense=False,
    )


@pytest.fixture(params=["cxx", "numpy"], autouse=True)
def mask_path(request, monkeypatch):
    """Every test runs with the C++ finite-point mask and with the numpy one."""
    if request.param == "numpy":
        monkeypatch.setattr(pointcloud2, "_REAL_POINT_INDICES", None)
    elif pointcloud2._REAL_POINT_INDICES is None:
        pytest.skip("forestslam._core without real_point_indices")
    return request.param


@pytest.fixture
def cloud():
    rng = np.random.default_rng(3)
    n = 240
    return {
        "x": rng.uniform(-20, 20, n),
        "y": rng.uniform(-20, 20, n),
        "z": rng.uniform(-2, 5, n),
        "intensity": rng.uniform(0, 255, n).round(),
        "ring": rng.integers(0, 16, n),
        "time": np.linspace(0.0, 0.099, n),
    }


def test_padded_reordered_fields(cloud):
    # Fields out of order with gaps, point_step 40 (like PCL's aligned PointXYZI types).
    layout = [("time", 0, "f4"), ("z", 8, "f4"), ("y", 12, "f4"), ("x", 16, "f4")]
    layout += [("ring", 24, "u2"), ("intensity", 32, "f4")]
    scan = decode_pointcloud2(make_msg(cloud, layout, 40))
    xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float32)
    np.testing.assert_array_equal(scan.points, xyz.astype(np.float64))
    np.testing.assert_array_equal(scan.intensity, cloud["intensity"].astype(np.float32))
    np.testing.assert_array_equal(scan.ring, cloud["ring"])
    np.testing.assert_allclose(scan.time, cloud["time"], atol=1e-7)
    assert scan.stamp == pytest.approx(100.25, abs=1e-9)


@pytest.mark.parametrize("bigendian", [False, True])
def test_float64_and_byte_order(cloud, bigendian):
    layout = [("x", 0, "f8"), ("y", 8, "f8"), ("z", 16, "f8"), ("intensity", 24, "u1")]
    layout += [("ring", 25, "u2"), ("time", 27, "f8")]
    cloud["intensity"] = cloud["intensity"].astype(np.uint8)
    scan = decode_pointcloud2(make_msg(cloud, layout, 35, bigendian=bigendian))
    np.testing.assert_array_equal(scan.points[:, 0], cloud["x"])  # float64: exact
    np.testing.assert_array_equal(scan.points[:, 2], cloud["z"])
    np.testing.assert_array_equal(scan.ring, cloud["ring"])
    np.testing.assert_array_equal(scan.time, cloud["time"])
    np.testing.assert_array_equal(scan.intensity, cloud["intensity"])


def test_integer_coordinates_all_datatypes():
    n = 20
    for code in ("i1", "u1", "i2", "u2", "i4", "u4"):
        cols = {c: np.arange(1, n + 1) * (k + 1) for k, c in enumerate("xyz")}
        size = np.dtype(code).itemsize
        layout = [(c, k * size, code) for k, c in enumerate("xyz")]
        scan = decode_pointcloud2(make_msg(cols, layout, 3 * size + 1, bigendian=True))
        np.testing.assert_array_equal(scan.points[:, 1], cols["y"])


def test_organized_with_nan_holes_and_row_padding(cloud):
    rng = np.random.default_rng(5)
    holes = rng.random(len(cloud["x"])) < 0.3
    cloud["x"] = np.where(holes, np.nan, cloud["x"])
    cloud["y"][5] = np.inf
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4")]
    layout += [("ring", 20, "u2"), ("time", 24, "f4")]
    msg = make_msg(cloud, layout, 32, height=16, row_pad=12)
    assert structured_points(msg).shape == (16, 15)
    scan = decode_pointcloud2(msg)
    keep = ~holes
    keep[5] = False
    assert len(scan) == keep.sum()
    assert np.isfinite(scan.points).all()
    # The same mask applies to every per-point array.
    np.testing.assert_array_equal(scan.ring, cloud["ring"][keep])
    np.testing.assert_array_equal(scan.intensity, cloud["intensity"][keep].astype(np.float32))
    np.testing.assert_allclose(scan.time, cloud["time"][keep], atol=1e-7)
    np.testing.assert_allclose(scan.points[:, 2], cloud["z"][keep], atol=1e-5)


def test_origin_points_are_no_returns(cloud):
    cloud["x"][:10] = 0.0
    cloud["y"][:10] = 0.0
    cloud["z"][:10] = 0.0
    scan = decode_pointcloud2(make_msg(cloud, [(c, 4 * k, "f4") for k, c in enumerate("xyz")], 12))
    assert len(scan) == len(cloud["x"]) - 10


def test_ouster_t_nanoseconds_and_reflectivity(cloud):
    cols = dict(cloud, t=(cloud["time"] * 1e9).round(), reflectivity=cloud["intensity"])
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("t", 16, "u4")]
    layout += [("reflectivity", 20, "u2"), ("ring", 22, "u1")]
    cols["ring"] = cols["ring"].astype(np.uint8)
    scan = decode_pointcloud2(make_msg(cols, layout, 48))
    np.testing.assert_allclose(scan.time, cloud["time"], atol=1e-9)
    np.testing.assert_array_equal(scan.intensity, cloud["intensity"].astype(np.float32))
    assert scan.ring.dtype == np.uint16


def test_absolute_float64_timestamp_made_relative(cloud):
    stamp = 1_700_000_000.5
    cols = dict(cloud, timestamp=stamp + cloud["time"])
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("timestamp", 16, "f8")]
    scan = decode_pointcloud2(make_msg(cols, layout, 24, stamp=stamp))
    np.testing.assert_allclose(scan.time, cloud["time"], atol=1e-6)


def test_empty_cloud(cloud):
    msg = make_msg(
        {k: v[:0] for k, v in cloud.items()}, [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")], 12
    )
    scan = decode_pointcloud2(msg)
    assert len(scan) == 0 and scan.points.shape == (0, 3)


def test_bad_layouts_raise_input_error(cloud):
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")]
    msg = make_msg(cloud, layout, 12)
    msg.data = msg.data[:-5]
    with pytest.raises(InputError, match="bytes"):
        decode_pointcloud2(msg)
    msg = make_msg(cloud, layout, 12)
    msg.fields[2].offset = 10  # z runs past point_step
    with pytest.raises(InputError, match="overruns"):
        decode_pointcloud2(msg)
    msg = make_msg(cloud, [("x", 0, "f4"), ("y", 4, "f4")], 12)
    with pytest.raises(InputError, match="lack z"):
        decode_pointcloud2(msg)
    msg = make_msg(cloud, layout, 12)
    msg.fields[0].datatype = 9
    with pytest.raises(InputError, match="datatype"):
        decode_pointcloud2(msg)


def test_float_nanosecond_timestamps_and_empty_header_stamp(cloud):
    stamp_ns = 1_700_000_000_500_000_000
    cols = dict(cloud, timestamp=stamp_ns + cloud["time"] * 1e9)
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("timestamp", 12, "f8")]
    scan = decode_pointcloud2(make_msg(cols, layout, 20, stamp=stamp_ns * 1e-9))
    np.testing.assert_allclose(scan.time, cloud["time"], atol=1e-6)
    # header.stamp left at 0: the stamp becomes the earliest point time.
    scan = decode_pointcloud2(make_msg(cols, layout, 20, stamp=0.0))
    assert scan.stamp == pytest.approx(stamp_ns * 1e-9, abs=1e-6)
    np.testing.assert_allclose(scan.time, cloud["time"], atol=1e-6)
