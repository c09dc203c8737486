"""Prior tree maps for global localization: build, save/load (.npz), read from a tree CSV.

Map file format (``.npz``, numpy's zip of arrays; written atomically):

- ``format``: the string ``"forestslam-tree-map"``; ``version``: int, currently 1
- ``xy`` (M,2) float64 trunk positions in the map frame (metres)
- ``dbh_m`` (M,) float64 stem diameters, NaN where unknown; ``ids`` (M,) int64 tree ids
- ``triangles`` (T,3) int32 Delaunay triangles (counter-clockwise rows of ``xy``),
  ``neighbours`` (T,3) int32 (triangle across the edge opposite each vertex, -1 on the hull)
- ``star_vertices`` (S,6) int32 and ``star_features`` (S,8) float64
  ``[A0,l0,A1,l1,A2,l2,A3,l3]`` (area and squared perimeter of the centre triangle and of its
  neighbours across its edges counter-clockwise from the shortest)

Loading rebuilds the triangulation and index from ``xy`` (deterministic, ~10 ms per 1,000
trees); the derived arrays are stored so other tools can use the map without forestslam.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np

from forestslam.errors import InputError

log = logging.getLogger(__name__)

MAP_FORMAT = "forestslam-tree-map"
MAP_VERSION = 1
CLOUD_SUFFIXES = (".las", ".laz", ".ply", ".pcd", ".bin")


class TreeMap:
    """Map trunks ``xy`` (M,2) with the triangle-star index built over them."""

    def __init__(
        self,
        xy: np.ndarray,
        dbh_m: np.ndarray | None = None,
        ids: np.ndarray | None = None,
        duplicate_tolerance_m: float = 0.01,
    ) -> None:
        from forestslam import _core

        xy = np.asarray(xy, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise InputError(f"tree map: xy must have shape (M,2), got {xy.shape}")
        finite = np.isfinite(xy).all(axis=1)
        if not finite.all():
            log.warning("tree map: dropped %d trees with non-finite positions", (~finite).sum())
        n = len(xy)
        dbh = np.full(n, np.nan) if dbh_m is None else np.asarray(dbh_m, dtype=np.float64)
        ident = np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
        if dbh.shape != (n,) or ident.shape != (n,):
            raise InputError("tree map: dbh_m and ids must have one value per tree")
        self.xy = np.ascontiguousarray(xy[finite])
        self.dbh_m = dbh[finite]
        self.ids = ident[finite]
        self._index = _core.TreeMapIndex(
            self.xy, duplicate_tolerance_m, np.ascontiguousarray(self.dbh_m, dtype=np.float64)
        )
        if len(self.xy) >= 3 and len(self._index.triangles) == 0:
            log.warning("tree map: trunks are collinear, nothing to localize against")

    def __len__(self) -> int:
        return len(self.xy)

    def __repr__(self) -> str:
        return f"TreeMap({len(self)} trees, {len(self.triangles)} triangles, {self.n_stars} stars)"

    @property
    def triangles(self) -> np.ndarray:
        return self._index.triangles

    @property
    def neighbours(self) -> np.ndarray:
        return self._index.neighbours

    @property
    def n_stars(self) -> int:
        return len(self._index.stars.centre)

    @property
    def index(self):
        """The C++ index (``forestslam._core.TreeMapIndex``)."""
        return self._index

    def save(self, path: str | Path) -> Path:
        """Write the map file (format in the module docstring); returns the path."""
        from forestslam.io.atomic import atomic_write

        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        stars = self._index.stars
        buffer = io.BytesIO()
        np.savez_compressed(
            buffer,
            format=np.array(MAP_FORMAT),
            version=np.array(MAP_VERSION),
            xy=self.xy,
            dbh_m=self.dbh_m,
            ids=self.ids,
            triangles=self.triangles.astype(np.int32),
            neighbours=self.neighbours.astype(np.int32),
            star_vertices=stars.vertices.astype(np.int32),
            star_features=stars.features,
        )
        atomic_write(path, lambda f: f.write(buffer.getvalue()), mode="wb")
        return path

    @classmethod
    def load(cls, path: str | Path, config=None) -> TreeMap:
        """A map file written by ``save``, or a tree CSV (see ``from_csv``)."""
        from forestslam.io.tree_tables import is_tree_table

        path = Path(path)
        if path.exists() and is_tree_table(path):
            return cls.from_tree_table(path)
        if not path.is_file():
            raise InputError(f"{path}: map file not found")
        if path.suffix.lower() == ".csv":
            return cls.from_csv(path)
        if path.suffix.lower() in CLOUD_SUFFIXES:
            t_h = config.trunk_height_offset_m if config is not None else 1.0
            return cls.from_cloud(path, height_offset_m=t_h)
        try:
            with np.load(path, allow_pickle=False) as data:
                if "format" not in data or str(data["format"]) != MAP_FORMAT:
                    raise InputError(f"{path}: not a forestslam tree map (.npz without 'format')")
                version = int(data["version"])
                if version > MAP_VERSION:
                    raise InputError(f"{path}: map version {version} is newer than supported")
                return cls(data["xy"], data["dbh_m"], data["ids"])
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"{path}: cannot read tree map ({exc})") from None

    @classmethod
    def from_csv(cls, path: str | Path) -> TreeMap:
        """Tree CSV with columns x, y and optionally dbh_m (or dbh_cm, dbh) and id (or tree):
        forestslam's trees.csv or a field inventory; extra columns (plot, height_m...) ignored."""
        from forestslam.io import read_trees_csv

        columns = {k.strip().lower(): v for k, v in read_trees_csv(path).items()}
        if "x" not in columns or "y" not in columns:
            raise InputError(f"{path}: tree CSV needs x and y columns, has {sorted(columns)}")
        xy = np.column_stack([columns["x"], columns["y"]])
        if "dbh_m" in columns:
            dbh = columns["dbh_m"]
        elif "dbh_cm" in columns:
            dbh = columns["dbh_cm"] / 100.0
        elif "dbh" in columns:
            dbh = columns["dbh"]
        else:
            dbh = None
        ids = None
        for name in ("id", "tree"):
            if name in columns and np.isfinite(columns[name]).all():
                ids = columns[name].astype(np.int64)
                break
        return cls(xy, dbh, ids)

    @classmethod
    def from_tree_table(cls, path: str | Path) -> TreeMap:
        """Trees of another mapper's per-frame tables (RealtimeTrees / TreeLoc layout, or the
        packed ``trees.csv.gz`` with a ``frame`` column) moved into the world frame by the
        table's trajectory and merged across frames."""
        from forestslam.io.tree_tables import read_tree_table
        from forestslam.localization.tables import table_map_xy

        xy, dbh = table_map_xy(read_tree_table(path))
        log.info("%s: %d trees from the tree table", path, len(xy))
        return cls(xy, dbh)

    @classmethod
    def from_cloud(cls, path: str | Path, **options) -> TreeMap:
        """Trunks extracted from a map point cloud (Li et al. Algorithm 1; options as for
        ``forestslam.localization.extract_trunks``), e.g. an accumulated harvester map."""
        from forestslam.io import read_cloud
        from forestslam.localization.localize import extract_trunks

        xy = extract_trunks(read_cloud(path).points, **options)
        log.info("%s: %d trunks extracted from the map cloud", path, len(xy))
        return cls(xy)


def build_map(xy: np.ndarray, dbh_m: np.ndarray | None = None) -> TreeMap:
    """Triangulate map trunks ``xy`` (M,2) and index their triangle stars."""
    return TreeMap(xy, dbh_m)


def load_map(path: str | Path, config=None) -> TreeMap:
    """A saved map (.npz), a tree CSV with x, y[, dbh_m], a map point cloud
    (.las/.laz/.ply/.pcd/.bin: trunks extracted by ``extract_trunks``) or another mapper's
    tree tables (a directory of TreeManagerState_<k>.csv + trajectory.txt, or a packed
    trees.csv[.gz] with a frame column). ``config`` (LocalizationConfig): t_h of the trunk
    extraction from clouds (2 m in paper mode)."""
    return TreeMap.load(path, config)
