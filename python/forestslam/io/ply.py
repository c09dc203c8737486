"""PLY point clouds: the `vertex` element (ascii, binary little/big endian); other elements
after it (faces) are ignored."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.atomic import atomic_write

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint"}
_NAMES |= {"f4": "float", "f8": "double"}


def read_ply(path: str | Path) -> np.ndarray:
    """A .ply file -> structured array of its vertices."""
    path = Path(path)
    blob = path.read_bytes()
    if not blob.startswith(b"ply"):
        raise InputError(f"{path}: not a PLY file (no 'ply' magic)")
    end = blob.find(b"end_header")
    if end < 0:
        raise InputError(f"{path}: PLY header has no end_header")
    body_start = blob.index(b"\n", end) + 1
    lines = blob[:end].decode("ascii", errors="replace").splitlines()
    fmt, element, count, props = None, None, 0, []
    vertex_seen = False
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info", "ply"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            if vertex_seen:
                break
            element, count = words[1], int(words[2])
            if element != "vertex":
                raise InputError(f"{path}: PLY element {element!r} before 'vertex' unsupported")
            vertex_seen = True
        elif words[0] == "property" and element == "vertex":
            if words[1] == "list":
                raise InputError(f"{path}: list property in PLY vertex element unsupported")
            code = _TYPES.get(words[1])
            if code is None:
                raise InputError(f"{path}: PLY property type {words[1]!r} unsupported")
            props.append((words[2], code))
    if not vertex_seen:
        raise InputError(f"{path}: PLY file without a vertex element")
    order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}.get(fmt or "")
    if order is None:
        raise InputError(f"{path}: PLY format {fmt!r} unsupported")
    dtype = np.dtype([(name, order + code) for name, code in props])
    body = blob[body_start:]
    if fmt == "ascii":
        if count == 0:
            return np.zeros(0, dtype=dtype)
        try:
            table = np.loadtxt(
                io.StringIO(body.decode("ascii", errors="replace")), ndmin=2, max_rows=count
            )
        except ValueError as exc:
            raise InputError(f"{path}: bad ASCII PLY data ({exc})") from None
        if table.shape[0] != count or table.shape[1] < len(props):
            raise InputError(f"{path}: ASCII PLY has {table.shape} values for {count} vertices")
        out = np.zeros(count, dtype=dtype)
        for k, (name, _code) in enumerate(props):
            out[name] = table[:, k]
        return out
    if len(body) < count * dtype.itemsize:
        raise InputError(f"{path}: PLY truncated ({len(body)} bytes for {count} vertices)")
    return np.frombuffer(body, dtype=dtype, count=count).copy()


def write_ply(path: str | Path, arr: np.ndarray) -> None:
    """Structured array -> binary little-endian PLY, atomically."""
    names = arr.dtype.names
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {len(arr)}"]
    for name in names:
        code = arr.dtype[name].str.lstrip("<>|=")
        if code not in _NAMES:
            raise InputError(f"PLY cannot store field {name} of type {arr.dtype[name]}")
        lines.append(f"property {_NAMES[code]} {name}")
    header = ("\n".join([*lines, "end_header"]) + "\n").encode()
    packed = arr.astype([(k, arr.dtype[k].newbyteorder("<")) for k in names])
    atomic_write(path, lambda f: f.write(header + packed.tobytes()), "wb")
