"""The result of per-scan perception: detected stems, all in the sensor (input) frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Where each stem's breast height (1.3 m above its base) came from (Stems.breast_source).
BREAST_HEIGHT_SOURCES = (
    "ground",  # the local ground under the stem
    "lowest point",  # no ground: the stem's lowest point is its base
    "slice middle",  # no ground, stem shorter than the band: the middle of the slice
    "explicit",  # given by the caller (breast_height_z)
)


# A single scan's DBH is reported (Stems.reported_dbh, `forestslam detect`) only when its
# expected error (Stems.dbh_std) is within one 2 cm diameter class; the others stay NaN there.
# Stems.dbh keeps every estimate (the tree map fuses them with its own rules).
REPORT_MAX_DBH_STD_M = 0.02


@dataclass
class Stems:
    """K stems of one scan.

    xy (K,2) breast-height centres (1.3 m above local ground); z (K,) their height;
    dbh (K,) metres, NaN where no diameter fit was accepted; mean (K,3) and cov (K,3,3) of the
    stem points (the Gaussians of shape-to-shape registration); axis (K,3) principal axis
    (unit, pointing up); base_z (K,) local ground height; points list of (Mi,3);
    ground (G,3) ground points thinned to one per voxel; diameters list of per-stem fit
    qualities (forestslam._core.StemDiameter: circle / cylinder / silhouette with radius,
    inliers, rms_m, arc_coverage, score; method; the cylinder is not fitted, valid False,
    when an accepted silhouette or band circle decides unless DiameterConfig.fit_all);
    timing dict of per-stage wall-clock milliseconds; cpu_ms the same stages in CPU time of
    the calling thread (the one-core cost); counts dict of per-stage point / cluster counts;
    breast_source (K,) index into BREAST_HEIGHT_SOURCES.
    """

    xy: np.ndarray
    dbh: np.ndarray
    z: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    axis: np.ndarray
    points: list[np.ndarray]
    base_z: np.ndarray
    ground: np.ndarray
    diameters: list = field(default_factory=list)  # of forestslam._core.StemDiameter
    timing: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    cpu_ms: dict[str, float] = field(default_factory=dict)
    breast_source: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.xy)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(len(self), dtype=np.int64)

    @property
    def dbh_std(self) -> np.ndarray:
        """(K,) expected error (1 sigma) of dbh: angular sampling and scan-line spread for the
        silhouette, the fit covariance for the circle / cylinder; NaN without a DBH."""
        if not self.diameters:
            return np.full(len(self), np.nan)
        return np.array([float(d.dbh_std) for d in self.diameters])

    def reported_dbh(self, max_std_m: float = REPORT_MAX_DBH_STD_M) -> np.ndarray:
        """(K,) dbh where its expected error is at most max_std_m, else NaN."""
        return np.where(self.dbh_std <= max_std_m, self.dbh, np.nan)

    @classmethod
    def empty(cls, ground: np.ndarray | None = None, timing: dict | None = None) -> Stems:
        return cls(
            xy=np.zeros((0, 2)),
            dbh=np.zeros(0),
            z=np.zeros(0),
            mean=np.zeros((0, 3)),
            cov=np.zeros((0, 3, 3)),
            axis=np.zeros((0, 3)),
            points=[],
            base_z=np.zeros(0),
            ground=np.zeros((0, 3)) if ground is None else ground,
            timing=dict(timing or {}),
        )

    def select(self, mask: np.ndarray) -> Stems:
        """The stems selected by a boolean mask or index array (ground and timing kept)."""
        idx = np.arange(len(self))[mask]
        return Stems(
            xy=self.xy[idx],
            dbh=self.dbh[idx],
            z=self.z[idx],
            mean=self.mean[idx],
            cov=self.cov[idx],
            axis=self.axis[idx],
            points=[self.points[i] for i in idx],
            base_z=self.base_z[idx],
            ground=self.ground,
            diameters=[self.diameters[i] for i in idx] if self.diameters else [],
            timing=dict(self.timing),
            counts=dict(self.counts),
            cpu_ms=dict(self.cpu_ms),
            breast_source=self.breast_source[idx]
            if len(self.breast_source)
            else self.breast_source,
        )
