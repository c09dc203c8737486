"""Cloud files and folders: every writer round-trips through its reader; PCD in all three
encodings; stamps from names, times.txt, per-point times or the rate; bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io import open_source, read_cloud, read_scans, write_cloud
from forestslam.io.pcd import read_pcd, write_pcd
from forestslam.io.ply import read_ply, write_ply

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def need_lzf() -> None:
    core = pytest.importorskip("forestslam._core", reason="LZF needs the compiled module")
    if not hasattr(core, "lzf_decompress"):
        pytest.skip("this forestslam._core build predates LZF")


@pytest.fixture
def cloud():
    rng = np.random.default_rng(11)
    points = rng.uniform(-50, 50, (3000, 3)) + np.array([1e3, 2e3, 0])
    intensity = rng.integers(0, 255, 3000).astype(np.float32)
    return points, intensity


@pytest.mark.parametrize(
    ("suffix", "atol"),
    [(".laz", 5e-5), (".las", 5e-5), (".ply", 0), (".pcd", 0), (".npy", 0), (".bin", 2.5e-4)],
)
def test_write_read_cloud(tmp_path, cloud, suffix, atol):
    points, intensity = cloud
    path = tmp_path / f"c{suffix}"
    write_cloud(path, points, intensity)
    scan = read_cloud(path)
    np.testing.assert_allclose(scan.points, points, atol=atol, rtol=0)
    np.testing.assert_array_equal(scan.intensity, intensity)
    write_cloud(path, points)  # overwrite, without intensity
    scan = read_cloud(path)
    assert len(scan) == len(points)
    assert scan.intensity is None or not scan.intensity.any()


def test_laz_is_compressed_and_rounds_intensity(tmp_path, cloud):
    points, _ = cloud
    write_cloud(tmp_path / "a.laz", points, np.full(len(points), 12.6))
    write_cloud(tmp_path / "a.las", points)
    assert (tmp_path / "a.laz").stat().st_size < 0.6 * (tmp_path / "a.las").stat().st_size
    np.testing.assert_array_equal(read_cloud(tmp_path / "a.laz").intensity, 13)


def _structured(n: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    arr = np.zeros(
        n,
        dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "u1"), ("ring", "u2"),
               ("time", "f8"), ("normal", "f4", (3,))],
    )  # fmt: skip
    for c in "xyz":
        arr[c] = rng.normal(0, 10, n)
    arr["intensity"] = rng.integers(0, 255, n)
    arr["ring"] = rng.integers(0, 32, n)
    arr["time"] = np.linspace(0, 0.1, n)
    arr["normal"] = rng.normal(size=(n, 3))
    return arr


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_encodings(tmp_path, data):
    if data == "binary_compressed":
        need_lzf()
    arr = _structured(2000)
    arr["x"][7] = np.nan  # a hole
    path = tmp_path / f"{data}.pcd"
    write_pcd(path, arr, data=data)
    back = read_pcd(path)
    assert back.dtype.names == arr.dtype.names
    for name in arr.dtype.names:
        np.testing.assert_array_equal(back[name], arr[name])
    scan = read_cloud(path)
    assert len(scan) == 1999
    np.testing.assert_array_equal(scan.ring, np.delete(arr["ring"], 7))
    np.testing.assert_allclose(scan.time, np.delete(arr["time"], 7))


def test_pcd_binary_compressed_hand_made_lzf(tmp_path):
    """A PCD whose LZF stream is written by hand (literal runs and a back reference)."""
    need_lzf()
    # Two points, fields x y z float32 stored field by field: x = [1, 1], y = [1, 1], z = [2, 3].
    one, two, three = (np.float32(v).tobytes() for v in (1, 2, 3))
    raw = one * 4 + two + three
    # Literal run of 4 ('one'); back reference of 12 bytes at distance 4: length code
    # 12 - 2 = 10 >= 7, so control (7 << 5) | (3 >> 8), extra length 10 - 7, low distance
    # byte 4 - 1; then a literal run of 8 ('two three').
    stream = bytes([3]) + one + bytes([7 << 5, 10 - 7, 4 - 1])
    stream += bytes([7]) + two + three
    header = (
        b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
        b"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary_compressed\n"
    )
    sizes = np.array([len(stream), len(raw)], dtype="<u4").tobytes()
    (tmp_path / "hand.pcd").write_bytes(header + sizes + stream)
    scan = read_cloud(tmp_path / "hand.pcd")
    np.testing.assert_array_equal(scan.points, [[1, 1, 2], [1, 1, 3]])
    (tmp_path / "bad.pcd").write_bytes(header + sizes + stream[:-3])
    with pytest.raises(InputError, match="bad.pcd"):
        read_cloud(tmp_path / "bad.pcd")


def test_ply_ascii_and_big_endian(tmp_path):
    arr = _structured(50)[["x", "y", "z", "intensity", "ring", "time"]]
    write_ply(tmp_path / "a.ply", arr)
    back = read_ply(tmp_path / "a.ply")
    for name in arr.dtype.names:
        np.testing.assert_array_equal(back[name], arr[name])
    lines = [
        "ply",
        "format ascii 1.0",
        "comment made by hand",
        "element vertex 2",
        "property double x",
        "property double y",
        "property double z",
        "property uchar intensity",
        "element face 1",
        "property list uchar int vertex_indices",
        "end_header",
        "1.5 2 3 7",
        "4 5 6.25 9",
        "3 0 1 1",
    ]
    (tmp_path / "b.ply").write_text("\n".join(lines) + "\n")
    scan = read_cloud(tmp_path / "b.ply")
    np.testing.assert_array_equal(scan.points, [[1.5, 2, 3], [4, 5, 6.25]])
    np.testing.assert_array_equal(scan.intensity, [7, 9])
    be = np.array([(1.0, 2.0, 3.0)], dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4")])
    head = "ply\nformat binary_big_endian 1.0\nelement vertex 1\n"
    head += "property float x\nproperty float y\nproperty float z\nend_header\n"
    (tmp_path / "c.ply").write_bytes(head.encode() + be.tobytes())
    np.testing.assert_array_equal(read_cloud(tmp_path / "c.ply").points, [[1, 2, 3]])


def test_npy_structured_and_kitti_bin(tmp_path):
    arr = _structured(30)
    np.save(tmp_path / "s.npy", arr)
    scan = read_cloud(tmp_path / "s.npy")
    np.testing.assert_array_equal(scan.ring, arr["ring"])
    table = np.arange(40, dtype="<f4").reshape(10, 4) + 1
    table.tofile(tmp_path / "000000.bin")
    scan = read_cloud(tmp_path / "000000.bin")
    np.testing.assert_array_equal(scan.points, table[:, :3])
    np.testing.assert_array_equal(scan.intensity, table[:, 3])
    (tmp_path / "odd.bin").write_bytes(b"\0" * 10)
    with pytest.raises(InputError, match="multiple of 16"):
        read_cloud(tmp_path / "odd.bin")


def test_las_gps_time_gives_stamp_and_relative_time(tmp_path):
    import laspy

    las = laspy.create(point_format=1, file_version="1.2")
    las.x, las.y, las.z = [1.0, 2.0, 3.0], [0.0, 1.0, 2.0], [5.0, 5.0, 5.0]
    las.gps_time = [250_000.0, 250_000.05, 250_000.1]
    las.write(tmp_path / "t.las")
    scan = read_cloud(tmp_path / "t.las")
    assert scan.stamp == pytest.approx(250_000.0)
    np.testing.assert_allclose(scan.time, [0.0, 0.05, 0.1], atol=1e-9)


def test_folder_stamps_from_names_in_time_order(tmp_path, cloud):
    points, intensity = cloud
    names = ["1600000000.300000.pcd", "1600000000.100000.pcd", "1600000000.200000.pcd"]
    for k, name in enumerate(names):
        write_cloud(tmp_path / name, points[k * 10 : k * 10 + 10], intensity[:10])
    scans = list(read_scans(tmp_path))
    assert [s.stamp for s in scans] == pytest.approx([1600000000.1, 1600000000.2, 1600000000.3])
    np.testing.assert_array_equal(scans[0].points, points[10:20])
    for k, ns in enumerate((1600000000200000000, 1600000000100000000)):
        write_cloud(tmp_path / f"ns/{ns}.npy", points[k : k + 10])
    assert [s.stamp for s in read_scans(tmp_path / "ns")] == pytest.approx(
        [1600000000.1, 1600000000.2]
    )


def test_folder_times_txt_and_rate(tmp_path, cloud):
    points, _ = cloud
    velo = tmp_path / "seq" / "velodyne"
    for k in range(12):  # natural order: 2 before 10
        write_cloud(velo / f"{k}.bin", points[k : k + 10])
    scans = list(read_scans(velo, rate_hz=5.0))
    assert [s.stamp for s in scans] == pytest.approx(np.arange(12) / 5.0)
    np.testing.assert_allclose(scans[10].points, points[10:20], atol=1e-4)
    np.savetxt(tmp_path / "seq" / "times.txt", np.arange(12) * 0.1 + 3.0)
    assert [s.stamp for s in read_scans(velo)] == pytest.approx(np.arange(12) * 0.1 + 3.0)
    source = open_source(velo)
    assert source.format == "bin-folder" and len(source) == 12 and source.topics() == []
    assert source.fields() == {"x": "float32", "y": "float32", "z": "float32",
                               "intensity": "float32"}  # fmt: skip


def test_folder_skips_a_corrupt_file_and_counts_it(tmp_path, cloud):
    points, _ = cloud
    for k in range(3):
        write_cloud(tmp_path / f"{k}.ply", points[k : k + 10])
    (tmp_path / "1.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 9\n")
    stream = read_scans(tmp_path)
    assert len(list(stream)) == 2
    assert stream.stats.skipped == 1 and any("1.ply" in w for w in stream.stats.warnings)


def test_bad_inputs(tmp_path, cloud):
    with pytest.raises(InputError, match="unsupported cloud file type '.xyz'"):
        read_cloud(tmp_path / "a.xyz")
    with pytest.raises(InputError, match="not found"):
        read_cloud(tmp_path / "a.laz")
    for name, content in (("g.pcd", b"garbage\n"), ("g.ply", b"garbage"), ("g.laz", b"junk"),
                          ("g.npy", b"junk")):  # fmt: skip
        (tmp_path / name).write_bytes(content)
        with pytest.raises(InputError, match=name):
            read_cloud(tmp_path / name)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no point-cloud files"):
        read_scans(tmp_path / "empty")
    mixed = tmp_path / "mixed"
    write_cloud(mixed / "a.ply", cloud[0][:3])
    write_cloud(mixed / "b.npy", cloud[0][:3])
    with pytest.raises(InputError, match="mixes"):
        read_scans(mixed)
    with pytest.raises(InputError, match="no topics"):
        read_scans(mixed / "a.ply", topic="/x")


def test_nan_only_and_single_point(tmp_path):
    write_cloud(tmp_path / "n.npy", np.full((5, 3), np.nan))
    assert len(read_cloud(tmp_path / "n.npy")) == 0
    write_cloud(tmp_path / "one.ply", np.array([[1.0, 2.0, 3.0]]))
    assert len(read_cloud(tmp_path / "one.ply")) == 1
    write_cloud(tmp_path / "zero.laz", np.zeros((0, 3)))
    assert len(read_cloud(tmp_path / "zero.laz")) == 0


@pytest.mark.parametrize(
    ("name", "points"),
    [("stem/lidr_dbh_slice.laz", 1369), ("tls/treels_pine_plot.laz", None)],
)
def test_real_laz(name, points):
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"{path} absent (shared real data not mounted)")
    scan = read_cloud(path)
    assert len(scan) > 1000 and np.isfinite(scan.points).all()
    if points is not None:
        assert len(scan) == points
        assert scan.ring is not None  # the Ring extra dimension
    extent = scan.points.max(axis=0) - scan.points.min(axis=0)
    assert (extent[:2] > 0.2).all() and (extent[:2] < 200).all()


FIXTURES = Path(__file__).resolve().parent / "data" / "io"


def test_pcd_written_by_pcl():
    """binary_compressed files written by PCL itself (see tests/data/io/README.md)."""
    need_lzf()
    scan = read_cloud(FIXTURES / "xyzi_compressed.pcd")
    i = np.delete(np.arange(500), 7)  # point 7 is a NaN hole
    expected = np.column_stack([10 * np.cos(0.01 * i), 10 * np.sin(0.01 * i), 0.001 * i - 1])
    np.testing.assert_allclose(scan.points, expected, atol=1e-5)
    np.testing.assert_array_equal(scan.intensity, i % 100)
    arr = read_pcd(FIXTURES / "rgbnormal_compressed.pcd")
    i = np.arange(300)
    np.testing.assert_array_equal(arr["x"], i)
    np.testing.assert_array_equal(arr["z"], 0.5 * i)
    np.testing.assert_array_equal(arr["rgb"] >> 16 & 0xFF, i % 255)
    np.testing.assert_array_equal(arr["rgb"] & 0xFF, 4)
    np.testing.assert_array_equal(arr["normal_z"], 1)
    np.testing.assert_array_equal(arr["curvature"], 0.25)


def test_laz_large_extent_and_non_finite(tmp_path):
    utm = np.array([[500_000.0, 5_000_000.0, 100.0], [501_000.0, 5_000_000.5, 101.25]])
    write_cloud(tmp_path / "utm.laz", utm)
    np.testing.assert_allclose(read_cloud(tmp_path / "utm.laz").points, utm, atol=5e-5)
    wide = np.array([[1.0, 0.0, 1.0], [1e6, 1.0, 1.0]])  # 1000 km: coarser, still exact-ish
    write_cloud(tmp_path / "wide.laz", wide)
    np.testing.assert_allclose(read_cloud(tmp_path / "wide.laz").points, wide, atol=5e-3)
    write_cloud(tmp_path / "nan.laz", np.array([[np.nan, 0.0, 0.0], [1.0, 2.0, 3.0]]), [5, 6])
    scan = read_cloud(tmp_path / "nan.laz")  # LAS has no NaN: the point is left out
    np.testing.assert_array_equal(scan.points, [[1, 2, 3]])
    np.testing.assert_array_equal(scan.intensity, [6])
