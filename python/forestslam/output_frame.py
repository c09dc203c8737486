"""Where a run's outputs are expressed.

The run computes in its odometry frame (the first scan's sensor frame). Its outputs are moved,
in float64, first into the prior map's coordinates once the run is placed there
(`forestslam.multisession.prior`), then into the coordinate reference system of the
georeference (`forestslam.georef`: `--crs`, with `--georef` for a run without a prior map).
Without either, outputs stay in the odometry frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import transform_points
from forestslam.georef import Georeference


@dataclass
class OutputFrame:
    georef: Georeference = field(default_factory=Georeference)
    prior: object | None = None  # a multisession.PriorTracker

    def __post_init__(self) -> None:
        moved = not np.array_equal(self.georef.T_crs_local, np.eye(4))
        if self.prior is not None and moved:
            raise InputError(
                "--georef places a run without a prior map: with --prior-map the map's own "
                "coordinates are used (give its CRS with --crs)"
            )

    def T(self) -> np.ndarray:
        """(4,4) output frame <- odometry frame."""
        T_map_odom = self.prior.T_map_odom() if self.prior is not None else np.eye(4)
        return self.georef.T_crs_local @ T_map_odom

    def poses(self, poses: np.ndarray) -> np.ndarray:
        return np.einsum("ij,njk->nik", self.T(), np.asarray(poses, dtype=np.float64))

    def points(self, points: np.ndarray) -> np.ndarray:
        return transform_points(self.T(), points)

    def table(self, table: dict) -> dict:
        """A tree table in the prior map's coordinates (or the odometry frame without one) moved
        into the output frame."""
        if self.prior is None and self.georef.is_identity:
            return table
        n = len(table["x"])
        z = np.asarray(table.get("z", np.zeros(n)), dtype=np.float64)
        xyz = np.column_stack([table["x"], table["y"], np.nan_to_num(z)])
        if self.prior is None:
            xyz = self.points(xyz)
        else:  # express_table put x, y in map coordinates already
            xyz = self.georef.points(xyz)
        out = dict(table)
        out.update(x=xyz[:, 0], y=xyz[:, 1])
        if "z" in table:
            out["z"] = np.where(np.isfinite(z), xyz[:, 2], np.nan)
        return out

    @property
    def in_crs(self) -> bool:
        """Whether the outputs are in the georeference's CRS (a run with a prior map only once
        it is placed there: never claim a CRS for coordinates that are not in it)."""
        placed = self.prior is None or self.prior.placed
        return self.georef.crs is not None and placed

    @property
    def crs(self):
        """The pyproj CRS of the outputs, or None."""
        return self.georef.pyproj_crs() if self.in_crs else None

    def crs_urn(self) -> str | None:
        return self.georef.ogc_urn() if self.in_crs else None

    def to_dict(self) -> dict:
        frame = "CRS " + self.georef.crs if self.georef.crs else "local"
        if self.prior is not None:
            frame = ("prior map" if self.prior.placed else "own (never placed)") + f", {frame}"
        return {"frame": frame, **self.georef.to_dict()}
