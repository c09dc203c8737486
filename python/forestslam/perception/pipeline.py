"""Per-scan tree-stem perception: the facade `detect` and every stage on its own.

The chain (all C++, forestslam._core): intensity filter -> approximate progressive
morphological ground filter -> adaptive ring-based normal filter -> coarse clusters (range-image
divide-and-merge for spinning / solid-state scans, 3D Euclidean for `map` / `tls` clouds) ->
adaptive DBSCAN -> SVD stem classification and merge -> local ground, breast-height centre and
DBH (SAC cylinder and robust circle fit, chosen by quality).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from forestslam.errors import InputError
from forestslam.io.scan import Scan
from forestslam.perception.config import PerceptionConfig
from forestslam.perception.stems import Stems
from forestslam.sensors import SensorProfile, load_profile

log = logging.getLogger(__name__)

MAX_POINTS = 50_000_000  # beyond this a cloud is refused rather than exhausting memory


def _core():
    from forestslam import _core

    return _core


def sensor_geometry(sensor: str | SensorProfile):
    """The sensor facts the C++ chain needs: a typed forestslam._core.SensorGeometry."""
    profile = load_profile(sensor)
    g = _core().SensorGeometry()
    g.has_range_image = bool(profile.has_range_image)
    g.image_rows = int(profile.image_rows)
    g.image_cols = int(profile.image_cols)
    g.horizontal_fov_rad = math.radians(profile.horizontal_fov_deg)
    if profile.channels > 0:
        g.vertical_angles_rad = [float(a) for a in profile.vertical_angles_rad]
    g.theta_v_rad = float(profile.theta_v_rad)
    g.azimuth_step_rad = math.radians(profile.azimuth_resolution_deg)
    return g


def core_options(
    config: PerceptionConfig,
    profile: SensorProfile,
    has_intensity: bool = True,
    breast_height_z: float | None = None,
):
    """The C++ PerceptionConfig of `config` through the one config bridge (unknown keys and
    wrong types raise InputError naming the key). The profile's intensity threshold applies when
    the config enables the filter and the scan has intensity; `breast_height_z` None: NaN."""
    from forestslam.odometry.bridge import fill_core

    options = fill_core(config, _core().PerceptionConfig(), "perception", skip=_PYTHON_ONLY)
    threshold = profile.intensity_threshold
    use = config.intensity_filter and threshold is not None and has_intensity
    options.intensity_threshold = float(threshold) if use else math.nan
    options.breast_height_z = math.nan if breast_height_z is None else float(breast_height_z)
    return options


_PYTHON_ONLY = ("intensity_filter",)  # decides options.intensity_threshold above


def _stage_options(config, where: str, core_cls: str):
    """One sub-config (ground, filter, ...) as its typed C++ struct."""
    from forestslam.odometry.bridge import fill_core

    return fill_core(config, getattr(_core(), core_cls)(), f"perception.{where}")


def _as_scan(scan: Scan | np.ndarray) -> Scan:
    if isinstance(scan, Scan):
        points = scan.points
    else:
        points = np.asarray(scan, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"points must have shape (N,3), got {points.shape}")
        scan = Scan(0.0, points)
        points = scan.points
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"scan points must have shape (N,3), got {points.shape}")
    if len(points) > MAX_POINTS:
        raise InputError(
            f"cloud has {len(points):,} points, more than {MAX_POINTS:,}: crop or thin it first"
        )
    return scan


def _ring(profile: SensorProfile, scan: Scan) -> np.ndarray | None:
    if scan.ring is None or not profile.has_range_image or len(scan) == 0:
        return None
    ring = np.asarray(scan.ring).astype(np.int32)
    if ring.min() < 0 or ring.max() >= profile.image_rows:
        log.warning(
            "ring field spans %d..%d, outside the %d rows of %s: using elevation angles",
            ring.min(),
            ring.max(),
            profile.image_rows,
            profile.name,
        )
        return None
    return ring


def detect(
    scan: Scan | np.ndarray,
    sensor: str | SensorProfile,
    config: PerceptionConfig | None = None,
    breast_height_z: float | None = None,
) -> Stems:
    """Stems of one scan (or one map / TLS cloud with sensor `map` / `tls`), sensor frame.

    Breast height is 1.3 m above the local ground; without ground, above the stem's lowest
    point, or the middle of a stem piece shorter than the band (a breast-height slice);
    `breast_height_z` (input frame) overrides all of them. Stems.breast_source says which.
    Empty, all-NaN or stem-less input gives empty Stems; a malformed array or an over-large
    cloud raises InputError.
    """
    config = config or PerceptionConfig()
    if breast_height_z is not None and not math.isfinite(breast_height_z):
        raise InputError(f"breast height z must be a finite number, not {breast_height_z}")
    profile = load_profile(sensor)
    scan = _as_scan(scan)
    if len(scan) == 0:
        return Stems.empty(timing={"total": 0.0})
    intensity = None
    if scan.intensity is not None:
        intensity = np.asarray(scan.intensity, dtype=np.float64)
    result = _core().perception_detect(
        scan.points,
        intensity,
        _ring(profile, scan),
        sensor_geometry(profile),
        profile.kind != "map",
        core_options(config, profile, scan.intensity is not None, breast_height_z),
    )
    stems = stems_from_core(result)
    k = len(stems.z)
    log.debug("%d stems, %d ground points, %.1f ms", k, len(stems.ground), stems.timing["total"])
    return stems


# ---- stages on their own (for debugging and for the ablation) ----


def intensity_filter(
    scan: Scan, sensor: str | SensorProfile, config: PerceptionConfig | None = None
) -> Scan:
    """The scan without returns brighter than the profile's intensity threshold (foliage);
    unchanged when the profile or the scan has no intensity."""
    profile = load_profile(sensor)
    config = config or PerceptionConfig()
    if not config.intensity_filter or profile.intensity_threshold is None:
        return scan
    if scan.intensity is None or len(scan) == 0:
        return scan
    rows = _core().perception_intensity_filter(
        np.asarray(scan.intensity, dtype=np.float64), float(profile.intensity_threshold)
    )
    return scan.select(np.asarray(rows, dtype=np.int64))


def segment_ground(points: np.ndarray, config: PerceptionConfig | None = None) -> np.ndarray:
    """(N,) bool ground mask of points (N,3) by the approximate progressive morphological
    filter (single-scan XY range limit of config.ground.max_range_m applies)."""
    config = config or PerceptionConfig()
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = _core().perception_segment_ground(
        points, _stage_options(config.ground, "ground", "GroundConfig")
    )
    return np.asarray(out.is_ground, dtype=bool)


@dataclass(frozen=True)
class GroundSurface:
    """The ground filter's height grid: `z` (rows = y cells, cols = x cells) in metres, NaN where
    unknown; cell (0, 0) spans [origin, origin + cell) in x and y."""

    z: np.ndarray
    origin: np.ndarray
    cell: float

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Ground height (K,) under points xy (K,2); NaN outside the grid or in unknown cells."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        idx = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        rows, cols = self.z.shape
        inside = (idx[:, 0] >= 0) & (idx[:, 1] >= 0) & (idx[:, 0] < cols) & (idx[:, 1] < rows)
        out = np.full(len(xy), np.nan)
        out[inside] = self.z[idx[inside, 1], idx[inside, 0]]
        return out

    def cell_centres(self) -> np.ndarray:
        """(K,3) centre xy and height of every known cell."""
        r, c = np.nonzero(np.isfinite(self.z))
        return np.c_[
            self.origin[0] + (c + 0.5) * self.cell,
            self.origin[1] + (r + 0.5) * self.cell,
            self.z[r, c],
        ]


def ground_surface(
    points: np.ndarray, config: PerceptionConfig | None = None, single_scan: bool = True
) -> GroundSurface:
    """Ground height grid of points (N,3) from the progressive morphological filter (the DTM the
    filter builds, holes of a few cells filled). A single scan keeps the XY range limit
    config.ground.max_range_m around its origin; a map or TLS cloud (`single_scan=False`) has
    none and may lie far from the origin (UTM)."""
    config = config or PerceptionConfig()
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    finite = points[np.isfinite(points).all(axis=1)]
    if len(finite) == 0:
        raise InputError("ground_surface: no finite points")
    ground = config.ground
    shift = np.zeros(3)
    if not single_scan:
        # Centred so the grid indices stay small; no range limit around a sensor.
        shift = np.r_[np.floor(finite[:, :2].mean(axis=0)), 0.0]
        extent = float(np.abs(finite[:, :2] - shift[:2]).max()) + 1.0
        ground = dataclasses.replace(ground, max_range_m=max(ground.max_range_m, extent))
    out = _core().perception_segment_ground(
        np.ascontiguousarray(finite - shift), _stage_options(ground, "ground", "GroundConfig")
    )
    return GroundSurface(
        z=np.array(out.grid.z, dtype=np.float64),
        origin=np.asarray(out.grid.origin, dtype=np.float64) + shift[:2],
        cell=float(out.grid.cell),
    )


def filter_normals(
    points: np.ndarray,
    sensor: str | SensorProfile,
    config: PerceptionConfig | None = None,
    candidates: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive (or fixed-radius) normal filter of non-ground points (N,3): returns the kept
    rows (M,) and their unit normals (M,3). No height band (no ground grid) here."""
    config = config or PerceptionConfig()
    profile = load_profile(sensor)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    rows = np.arange(len(points), dtype=np.int32) if candidates is None else candidates
    out = _core().perception_normal_filter(
        points,
        np.asarray(rows, dtype=np.int32),
        profile.theta_v_rad,
        _stage_options(config.filter, "filter", "NormalFilterConfig"),
    )
    return np.asarray(out.kept, dtype=np.int64), np.array(out.normals).reshape(-1, 3)


def coarse_clusters(
    points: np.ndarray,
    sensor: str | SensorProfile,
    config: PerceptionConfig | None = None,
    ring: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Coarse clusters (row arrays) of filtered points: range-image divide-and-merge when the
    sensor has a range image, else 3D Euclidean clustering."""
    config = config or PerceptionConfig()
    profile = load_profile(sensor)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    seg = _stage_options(config.segmentation, "segmentation", "SegmentationConfig")
    min_size = max(2, config.segmentation.min_points // 2)
    if profile.has_range_image:
        ring32 = None if ring is None else np.asarray(ring, dtype=np.int32)
        return _core().perception_range_image_clusters(
            points, ring32, sensor_geometry(profile), seg, min_size
        )
    return _core().perception_euclidean_clusters(
        points, config.segmentation.euclidean_tolerance_m, min_size
    )


def refine_cluster(
    points: np.ndarray, sensor: str | SensorProfile, config: PerceptionConfig | None = None
) -> list[np.ndarray]:
    """DBSCAN of one coarse cluster (M,3) with eps = k * theta_V * |mean_xy| (clamped)."""
    config = config or PerceptionConfig()
    profile = load_profile(sensor)
    seg = config.segmentation
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return []
    if profile.has_range_image:
        eps = seg.dbscan_k * profile.theta_v_rad * float(np.linalg.norm(points[:, :2].mean(0)))
        eps = float(np.clip(eps, seg.dbscan_min_eps_m, seg.dbscan_max_eps_m))
    else:
        eps = seg.map_dbscan_eps_m
    return _core().perception_dbscan(points, eps, seg.dbscan_min_neighbours)


@dataclass(frozen=True)
class ClusterClass:
    """classify_cluster's result: the cluster's SVD shape (forestslam._core.ClusterShape: mean,
    cov, axis, singular, length, width, axis_angle) and whether it is a stem."""

    shape: object
    is_stem: bool


def classify_cluster(
    points: np.ndarray, config: PerceptionConfig | None = None, up: np.ndarray | None = None
) -> ClusterClass:
    """SVD shape of one cluster (M,3) and whether it is a stem."""
    config = config or PerceptionConfig()
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    seg = _stage_options(config.segmentation, "segmentation", "SegmentationConfig")
    shape = _core().perception_cluster_shape(points, up)
    return ClusterClass(shape, bool(_core().perception_is_stem(shape, len(points), seg)))


def estimate_diameter(
    points: np.ndarray,
    base_z: float,
    normals: np.ndarray | None = None,
    config: PerceptionConfig | None = None,
    up: np.ndarray | None = None,
):
    """DBH of one stem's points (M,3) above ground height base_z: circle fit on the
    breast-height band and (with normals (M,3)) the SAC cylinder; forestslam._core.StemDiameter
    with both fits, the chosen `method` and `dbh` (NaN when none is accepted)."""
    config = config or PerceptionConfig()
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if normals is not None:
        normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    return _core().perception_estimate_diameter(
        points,
        normals,
        float(base_z),
        up,
        _stage_options(config.diameter, "diameter", "DiameterConfig"),
    )


def stems_from_core(result, fits: bool = True) -> Stems:
    """Stems from the C++ detection (forestslam._core.Detection), as both the detector and the
    odometry return it; fits False: without the per-stem fit qualities (diameters empty)."""
    k = len(result)
    return Stems(
        xy=np.asarray(result.xy).reshape(k, 2),
        dbh=np.asarray(result.dbh),
        z=np.asarray(result.z),
        mean=np.asarray(result.mean).reshape(k, 3),
        cov=np.asarray(result.cov).reshape(k, 3, 3),
        axis=np.asarray(result.axis).reshape(k, 3),
        points=result.points,  # a new list of (Mi,3) float64 arrays (copies) on every read
        base_z=np.asarray(result.base_z),
        ground=np.asarray(result.ground).reshape(-1, 3),
        diameters=list(result.diameters) if fits else [],
        timing=dict(result.timing),
        cpu_ms=dict(result.cpu_ms),
        counts=dict(result.counts),
        breast_source=np.asarray(result.breast_source, dtype=np.int64),
    )
