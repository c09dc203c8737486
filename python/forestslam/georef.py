"""Georeferencing: a projected CRS and the pose of the run's local frame in it.

A run computes in its own local frame (the first scan's sensor frame, or a prior map's frame):
metres near the origin, where float arithmetic and voxel keys are exact enough. A Georeference
moves outputs into a coordinate reference system at write time, in float64 throughout, so UTM
coordinates (10^5-10^7 m) keep millimetres. `--georef x,y,z,yaw_deg` gives the world pose of the
first scan's sensor frame; yaw in degrees, as `tls-register --initial-pose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import parse_yaw, planar_pose, transform_points


def parse_georef(text: str) -> np.ndarray:
    """`x,y,z,yaw_deg` -> T_crs_local (4,4) float64 (a yaw about z, then the offset; the yaw
    as geometry.parse_yaw reads it)."""
    *head, last = text.split(",")
    try:
        values = [float(v) for v in head] + [parse_yaw(last, "--georef")]
    except ValueError:
        values = []
    if len(values) != 4 or not np.all(np.isfinite(values)):
        raise InputError(f"--georef must be x,y,z,yaw_deg (four numbers), not {text!r}")
    x, y, z, yaw = values
    return planar_pose(x, y, yaw, z)


def _projected_crs(text: str):
    """A pyproj CRS for `text` (EPSG:N, WKT, PROJ string); geographic CRSs are refused since
    every output is in metres."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(text)
    except CRSError as exc:
        raise InputError(f"unknown coordinate reference system {text!r} ({exc})") from None
    if not crs.is_projected:
        raise InputError(
            f"{text} ({crs.name}) is not a projected CRS: forestslam writes metres, so give a "
            "projected one (for example the UTM zone, EPSG:326NN / EPSG:327NN)"
        )
    return crs


@dataclass(frozen=True)
class Georeference:
    """`crs`: the CRS's user text (None: local frame only); `T_crs_local` (4,4) float64."""

    crs: str | None = None
    T_crs_local: np.ndarray = field(default_factory=lambda: np.eye(4))

    @classmethod
    def from_options(cls, crs: str | None, georef: str | None) -> Georeference:
        if georef is not None and crs is None:
            raise InputError("--georef needs --crs (the CRS its coordinates are in)")
        T = parse_georef(georef) if georef is not None else np.eye(4)
        if crs is not None:
            _projected_crs(crs)
        return cls(crs, T)

    @property
    def is_identity(self) -> bool:
        return self.crs is None and np.array_equal(self.T_crs_local, np.eye(4))

    def pyproj_crs(self):
        return None if self.crs is None else _projected_crs(self.crs)

    def wkt(self) -> str | None:
        crs = self.pyproj_crs()
        return None if crs is None else crs.to_wkt()

    def epsg(self) -> int | None:
        crs = self.pyproj_crs()
        return None if crs is None else crs.to_epsg()

    def points(self, points_local: np.ndarray) -> np.ndarray:
        """(N,3) local -> (N,3) float64 in the CRS."""
        p = np.asarray(points_local, dtype=np.float64).reshape(-1, 3)
        return transform_points(self.T_crs_local, p)

    def xy(self, xy_local: np.ndarray, z_local: np.ndarray | None = None) -> np.ndarray:
        """(N,2) local -> (N,2) in the CRS (heights of 0 unless given)."""
        xy = np.asarray(xy_local, dtype=np.float64).reshape(-1, 2)
        z = np.zeros(len(xy)) if z_local is None else np.asarray(z_local, dtype=np.float64)
        return self.points(np.column_stack([xy, z]))[:, :2]

    def poses(self, T_local_sensor: np.ndarray) -> np.ndarray:
        """(K,4,4) poses in the local frame -> T_crs_sensor (K,4,4)."""
        return np.einsum("ij,kjl->kil", self.T_crs_local, np.asarray(T_local_sensor, np.float64))

    def ogc_urn(self) -> str | None:
        """The CRS as an OGC URN (GeoJSON's `crs` member), None without an EPSG code."""
        code = self.epsg()
        return None if code is None else f"urn:ogc:def:crs:EPSG::{code}"

    def to_dict(self) -> dict:
        """What run.yaml records."""
        return {"crs": self.crs, "T_crs_local": np.round(self.T_crs_local, 9).tolist()}
