"""PCL .pcd files (v0.5-0.7): DATA ascii, binary and binary_compressed (LZF, in C++)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.atomic import atomic_write

_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4"}
_TYPES |= {("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT")
_HEADER_KEYS += ("POINTS", "DATA")


def _lzf():
    try:
        from forestslam import _core
    except ImportError as exc:
        raise InputError(
            f"binary_compressed PCD needs the compiled forestslam._core ({exc})"
        ) from None
    if not hasattr(_core, "lzf_decompress"):
        raise InputError("binary_compressed PCD: this forestslam._core build lacks LZF")
    return _core


def _parse_header(path: Path, blob: bytes) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in header:
        end = blob.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{path}: PCD header has no DATA line")
        line = blob[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        if key.upper() not in _HEADER_KEYS:
            raise InputError(f"{path}: not a PCD file (unexpected header line {line[:40]!r})")
        header[key.upper()] = values
    for key in ("FIELDS", "SIZE", "TYPE", "DATA"):
        if key not in header:
            raise InputError(f"{path}: PCD header lacks {key}")
    return header, pos


def _dtype(path: Path, header: dict[str, list[str]]) -> np.dtype:
    names = header["FIELDS"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    if not len(names) == len(header["SIZE"]) == len(header["TYPE"]) == len(counts):
        raise InputError(f"{path}: PCD FIELDS, SIZE, TYPE and COUNT differ in length")
    formats, seen = [], []
    for name, size, typ, count in zip(names, header["SIZE"], header["TYPE"], counts, strict=True):
        code = _TYPES.get((typ.upper(), int(size)))
        if code is None:
            raise InputError(f"{path}: PCD field {name} has unsupported TYPE {typ} SIZE {size}")
        # PCL names padding fields "_"; numpy needs unique names.
        unique = name if name not in seen else f"{name}_{len(seen)}"
        seen.append(unique)
        formats.append(np.dtype("<" + code) if count == 1 else np.dtype(("<" + code, (count,))))
    return np.dtype({"names": seen, "formats": formats})


def read_pcd(path: str | Path) -> np.ndarray:
    """A .pcd file -> structured array of its points (height * width,)."""
    path = Path(path)
    blob = path.read_bytes()
    header, pos = _parse_header(path, blob)
    dtype = _dtype(path, header)
    width = int(header.get("WIDTH", ["0"])[0])
    height = int(header.get("HEIGHT", ["1"])[0])
    n = int(header.get("POINTS", [str(width * height)])[0])
    kind = header["DATA"][0].lower()
    body = blob[pos:]
    if kind == "ascii":
        text = body.decode("ascii", errors="replace")
        if n == 0:
            return np.zeros(0, dtype=dtype)
        try:
            values = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise InputError(f"{path}: bad ASCII PCD data ({exc})") from None
        columns = sum(int(np.prod(dtype[k].shape or (1,))) for k in range(len(dtype)))
        if values.shape != (n, columns):
            raise InputError(f"{path}: ASCII PCD has {values.shape} values, header says {n}")
        out = np.zeros(n, dtype=dtype)
        col = 0
        for name in dtype.names:
            width_k = int(np.prod(dtype[name].shape or (1,)))
            out[name] = values[:, col : col + width_k].reshape(out[name].shape)
            col += width_k
        return out
    if kind == "binary":
        if len(body) < n * dtype.itemsize:
            raise InputError(f"{path}: binary PCD truncated ({len(body)} bytes for {n} points)")
        return np.frombuffer(body, dtype=dtype, count=n).copy()
    if kind == "binary_compressed":
        if len(body) < 8:
            raise InputError(f"{path}: binary_compressed PCD truncated")
        csize, usize = np.frombuffer(body[:8], dtype="<u4")
        if usize != n * dtype.itemsize or len(body) < 8 + csize:
            raise InputError(f"{path}: binary_compressed PCD sizes do not match the header")
        try:
            raw = _lzf().lzf_decompress(body[8 : 8 + int(csize)], int(usize))
        except ValueError as exc:
            raise InputError(f"{path}: corrupt LZF data ({exc})") from None
        # Decompressed data is field after field (structure of arrays).
        out = np.zeros(n, dtype=dtype)
        offset = 0
        for name in dtype.names:
            field = dtype[name]
            size = field.itemsize * n
            values = np.frombuffer(
                raw, dtype=field.base, count=size // field.base.itemsize, offset=offset
            )
            out[name] = values.reshape(out[name].shape)
            offset += size
        return out
    raise InputError(f"{path}: unsupported PCD DATA {kind!r}")


def read_pcd_viewpoint(path: str | Path) -> np.ndarray | None:
    """The scanner position (3,) a .pcd header's VIEWPOINT gives (tx ty tz, in the cloud's
    frame); None when it has none, or PCL's default 0 0 0 (written whatever the origin)."""
    with Path(path).open("rb") as f:
        blob = f.read(1 << 16)  # the header: a few hundred bytes
    try:
        header, _ = _parse_header(Path(path), blob)
        t = np.array([float(v) for v in header.get("VIEWPOINT", [])[:3]])
    except (InputError, ValueError):
        return None
    return t if len(t) == 3 and np.all(np.isfinite(t)) and np.any(t != 0) else None


_PCD_TYPE = {"f": "F", "i": "I", "u": "U"}


def write_pcd(path: str | Path, arr: np.ndarray, data: str = "binary") -> None:
    """Structured array -> .pcd (DATA binary, binary_compressed or ascii), atomically."""
    names = arr.dtype.names
    fields = [arr.dtype[k] for k in names]
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format",
            "VERSION 0.7",
            "FIELDS " + " ".join(names),
            "SIZE " + " ".join(str(f.base.itemsize) for f in fields),
            "TYPE " + " ".join(_PCD_TYPE[f.base.kind] for f in fields),
            "COUNT " + " ".join(str(int(np.prod(f.shape or (1,)))) for f in fields),
            f"WIDTH {len(arr)}",
            "HEIGHT 1",
            "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {len(arr)}",
            f"DATA {data}",
            "",
        ]
    ).encode()
    layout = [(k, f.newbyteorder("<")) for k, f in zip(names, fields, strict=True)]
    packed = np.zeros(len(arr), dtype=layout)
    for k in names:
        packed[k] = arr[k]
    if data == "binary":
        body = packed.tobytes()
    elif data == "binary_compressed":
        soa = b"".join(np.ascontiguousarray(packed[k]).tobytes() for k in names)
        comp = _lzf().lzf_compress(soa)
        body = np.array([len(comp), len(soa)], dtype="<u4").tobytes() + comp
    elif data == "ascii":
        cols = [packed[k].reshape(len(arr), -1).astype(np.float64) for k in names]
        text = io.StringIO()
        np.savetxt(text, np.hstack(cols) if cols else np.zeros((0, 0)), fmt="%.17g")
        body = text.getvalue().encode()
    else:
        raise InputError(f"PCD DATA must be ascii, binary or binary_compressed, not {data!r}")
    atomic_write(path, lambda f: f.write(header + body), "wb")
