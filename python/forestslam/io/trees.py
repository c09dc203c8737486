"""Tree maps as CSV and GeoJSON, written atomically (a crash leaves the previous complete file)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.io.atomic import atomic_write_text


def _columns(columns: dict[str, np.ndarray], where: Path) -> dict[str, np.ndarray]:
    arrays = {str(k): np.asarray(v).reshape(-1) for k, v in columns.items()}
    lengths = {len(v) for v in arrays.values()}
    if len(lengths) > 1:
        sizes = {k: len(v) for k, v in arrays.items()}
        raise InputError(f"{where}: tree columns differ in length {sizes}")
    return arrays


def _format(values: np.ndarray) -> list[str]:
    if values.dtype.kind in "iub":
        return [str(int(v)) for v in values.tolist()]
    if values.dtype.kind == "f":
        return ["" if not np.isfinite(v) else f"{v:.6f}" for v in values.tolist()]
    return [str(v) for v in values.tolist()]


def write_trees_csv(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Columns (name -> (K,) array) in the given order to CSV; NaN is written as an empty cell.
    Floats with 6 decimals (micrometres for metres)."""
    path = Path(path)
    arrays = _columns(columns, path)
    out = io.StringIO()
    out.write(",".join(arrays) + "\n")
    cells = [_format(v) for v in arrays.values()]
    for row in zip(*cells, strict=True):
        out.write(",".join(row) + "\n")
    atomic_write_text(path, out.getvalue())


MAX_MEDIAN_DBH_M = 3.0  # above it a dbh_m column is not in metres


def read_trees_csv(path: str | Path) -> dict[str, np.ndarray]:
    """CSV with a header -> {column: array}: float64 where every cell is a number or empty
    (empty -> NaN), else the column's text (a `source` or `status` flag, a species)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: tree CSV not found")
    from forestslam.io.text import read_input_text

    lines = [ln for ln in read_input_text(path, "tree CSV").splitlines() if ln.strip()]
    if not lines:
        raise InputError(f"{path}: empty tree CSV")
    names = [n.strip() for n in lines[0].split(",")]
    rows = [ln.split(",") for ln in lines[1:]]
    if any(len(r) != len(names) for r in rows):
        raise InputError(f"{path}: rows with a number of cells other than {len(names)}")
    cells = np.array(rows, dtype=str).reshape(len(rows), len(names))
    table = {name: _column(cells[:, k]) for k, name in enumerate(names)}
    _check_dbh_unit(table, path)
    return table


def _check_dbh_unit(table: dict[str, np.ndarray], path: Path) -> None:
    """A `dbh_m` column whose median is above 3 m is not metres (no stand's median tree is that
    thick): centimetres or millimetres. Refused rather than read as giant trees."""
    dbh = table.get("dbh_m")
    if dbh is None or dbh.dtype.kind != "f" or not np.isfinite(dbh).any():
        return
    median = float(np.nanmedian(dbh))
    if median > MAX_MEDIAN_DBH_M:
        unit = "millimetres" if median > 300 else "centimetres"
        raise InputError(
            f"{path}: column dbh_m has a median of {median:g}, which looks like {unit}; "
            f"give the diameters in metres (or name a centimetre column dbh_cm)"
        )


def _column(cells: np.ndarray) -> np.ndarray:
    stripped = np.char.strip(cells)
    try:
        return np.where(stripped == "", "nan", stripped).astype(np.float64)
    except ValueError:
        return stripped.astype(object)


def write_trees_geojson(
    path: str | Path, columns: dict[str, np.ndarray], crs_name: str | None = None
) -> None:
    """A FeatureCollection of Points at (x, y[, z]) with every other column as properties.
    Coordinates are in the run's frame (metres); with `crs_name` (an OGC URN such as
    urn:ogc:def:crs:EPSG::32612) they are in that CRS and the collection names it in a `crs`
    member (GeoJSON 2008, read by QGIS and GDAL), else none is claimed."""
    path = Path(path)
    arrays = _columns(columns, path)
    if "x" not in arrays or "y" not in arrays:
        raise InputError(f"{path}: GeoJSON trees need x and y columns")
    coord_names = ["x", "y"] + (["z"] if "z" in arrays else [])
    props = [k for k in arrays if k not in coord_names]

    def value(v):
        v = v.item() if hasattr(v, "item") else v
        return None if isinstance(v, float) and not np.isfinite(v) else v

    n = len(arrays["x"])
    features = [
        {
            "type": "Feature",
            "geometry": {
                "type": "Point",
                "coordinates": [  # a tree without a known height is a 2D point
                    round(float(arrays[c][i]), 6)
                    for c in coord_names
                    if c != "z" or np.isfinite(arrays[c][i])
                ],
            },
            "properties": {k: value(arrays[k][i]) for k in props},
        }
        for i in range(n)
    ]
    collection: dict = {"type": "FeatureCollection"}
    if crs_name is not None:
        collection["crs"] = {"type": "name", "properties": {"name": crs_name}}
    collection["features"] = features
    text = json.dumps(collection, indent=1, allow_nan=False)
    atomic_write_text(path, text + "\n")
