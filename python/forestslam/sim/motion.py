"""Platform motion: a path through the stand that keeps clear of the stems, and the sensor pose
T_world_sensor as a continuous function of time (terrain-following roll/pitch plus vibration)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from forestslam.errors import InputError, ProcessingError
from forestslam.geometry import rotation_zyx, se2, transform_points
from forestslam.sim.config import MotionConfig
from forestslam.sim.stand import Stand
from forestslam.sim.terrain import Terrain

log = logging.getLogger(__name__)
SPACING_M = 0.25


@dataclass
class PlannedPath:
    xy: np.ndarray  # (M,2) samples about SPACING_M apart (one row: a static station)
    closed: bool
    min_clearance_m: float  # smallest distance from the path to a stem surface

    @property
    def static(self) -> bool:
        return len(self.xy) == 1

    @property
    def length_m(self) -> float:
        if self.static:
            return 0.0
        seg = np.linalg.norm(np.diff(self._ring(), axis=0), axis=1)
        return float(seg.sum())

    def _ring(self) -> np.ndarray:
        return np.vstack([self.xy, self.xy[:1]]) if self.closed else self.xy


def _resample(xy: np.ndarray, closed: bool, spacing: float = SPACING_M) -> np.ndarray:
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    if total <= 0:
        return xy[:1].copy()
    n = max(2, int(round(total / spacing)))
    s = np.linspace(0.0, total, n, endpoint=not closed)
    return np.column_stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])


def _smooth(xy: np.ndarray, closed: bool, weight: float = 0.3) -> np.ndarray:
    if closed:
        lap = 0.5 * (np.roll(xy, 1, axis=0) + np.roll(xy, -1, axis=0)) - xy
    else:
        lap = np.zeros_like(xy)
        lap[1:-1] = 0.5 * (xy[:-2] + xy[2:]) - xy[1:-1]
        if len(xy) >= 3:  # ends drift onto the line through their neighbours (no end kinks)
            lap[0] = 0.5 * ((2 * xy[1] - xy[2]) - xy[0])
            lap[-1] = 0.5 * ((2 * xy[-2] - xy[-3]) - xy[-1])
    return xy + weight * lap


def stem_clearance(xy: np.ndarray, stand: Stand) -> np.ndarray:
    """Distance from each path sample to the nearest stem surface (inf without trees)."""
    if len(stand) == 0:
        return np.full(len(xy), np.inf)
    from scipy.spatial import cKDTree

    k = min(8, len(stand))
    d, j = cKDTree(stand.xy).query(xy, k=k)
    d, j = d.reshape(len(xy), k), j.reshape(len(xy), k)
    return (d - stand.dbh[j] / 2).min(axis=1)


def _push_clear(xy: np.ndarray, closed: bool, stand: Stand, clearance: float) -> np.ndarray:
    """Move path samples out of the clearance disc of every stem, keeping the path smooth."""
    if len(stand) == 0:
        return xy
    from scipy.spatial import cKDTree

    tree = cKDTree(stand.xy)
    need_r = stand.dbh / 2 + clearance
    k = min(6, len(stand))
    n0 = len(xy)
    for _ in range(200):
        d, j = tree.query(xy, k=k)
        d, j = d.reshape(len(xy), k), j.reshape(len(xy), k)
        deficit = need_r[j] + 0.05 - d
        if (deficit <= 0).all():
            break
        away = xy[:, None, :] - stand.xy[j]
        # A stem right on the path: push sideways (perpendicular to the local direction).
        tangent = np.gradient(xy, axis=0)
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        tiny = d < 1e-6
        away[tiny] = np.broadcast_to(normal[:, None, :], away.shape)[tiny]
        d = np.maximum(d, 1e-6)
        # Over-push (gain 1.5) so the path escapes gaps narrower than the clearance instead of
        # settling between two stems where pushes and smoothing balance.
        push = (1.5 * np.clip(deficit, 0, None) / d)[:, :, None] * away
        xy = _resample(_smooth(xy + _capped(push.sum(axis=1)), closed, 0.25), closed)
        if len(xy) > 3 * n0:  # diverging (stems too dense for this clearance): give up here
            return xy
    # Relax: strong smoothing against plain pushes irons out the corners the over-push leaves
    # (a machine cannot turn on the spot) while keeping the clearance. Smoothing also shrinks a
    # loop (curve-shortening), so stop before it loses more than a tenth of its length.
    length0 = _polyline_length(xy, closed)
    for _ in range(150):
        previous = xy
        for _ in range(3):
            xy = _smooth(xy, closed, 0.5)
        d, j = tree.query(xy, k=k)
        d, j = d.reshape(len(xy), k), j.reshape(len(xy), k)
        deficit = need_r[j] + 0.05 - d
        away = (xy[:, None, :] - stand.xy[j]) / np.maximum(d, 1e-6)[:, :, None]
        xy = _resample(
            xy + _capped((np.clip(deficit, 0, None)[:, :, None] * away).sum(axis=1)), closed
        )
        if len(xy) > 3 * n0:
            return xy
        if _polyline_length(xy, closed) < 0.9 * length0:
            return previous
    return xy


def _polyline_length(xy: np.ndarray, closed: bool) -> float:
    pts = np.vstack([xy, xy[:1]]) if closed and len(xy) > 1 else xy
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _capped(step: np.ndarray, limit: float = 0.3) -> np.ndarray:
    """Per-sample displacement limited to `limit` metres, so pushes cannot blow up."""
    norm = np.linalg.norm(step, axis=1, keepdims=True)
    return step * np.minimum(1.0, limit / np.maximum(norm, 1e-12))


def _nominal(cfg: MotionConfig, centre: np.ndarray, heading: float, extent: np.ndarray):
    length = cfg.length_m
    if cfg.path == "loop":
        a_over_b = max(cfg.loop_aspect, 1e-3)
        phi = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
        unit = np.column_stack([a_over_b * np.cos(phi), np.sin(phi)])
        perimeter = np.linalg.norm(np.diff(np.vstack([unit, unit[:1]]), axis=0), axis=1).sum()
        local, closed = unit * (length / perimeter), True
    elif cfg.path == "line":
        local = np.array([[-length / 2, 0.0], [length / 2, 0.0]])
        closed = False
    elif cfg.path == "lawnmower":
        s = cfg.lane_spacing_m
        if s <= 0:
            raise InputError("motion.lane_spacing_m must be > 0")
        turn = np.pi * s / 2
        lane = cfg.lane_length_m or max(min(0.8 * float(extent[0]), length), 5.0)
        n = max(1, int(round((length + turn) / (lane + turn))))
        if not cfg.lane_length_m:  # fit the lanes to the asked length
            lane = max((length - (n - 1) * turn) / n, 1.0)
        pts = []
        for i in range(n):  # n lanes (a handful): build the polyline with semicircle turns
            y = (i - (n - 1) / 2) * s
            xs = np.linspace(-lane / 2, lane / 2, 50)
            if i % 2:
                xs = xs[::-1]
            pts.append(np.column_stack([xs, np.full(50, y)]))
            if i < n - 1:
                side = lane / 2 if i % 2 == 0 else -lane / 2
                sign = 1 if i % 2 == 0 else -1
                ang = np.linspace(-np.pi / 2, np.pi / 2, 30)[1:-1]
                pts.append(
                    np.column_stack(
                        [side + sign * s / 2 * np.cos(ang), y + s / 2 + s / 2 * np.sin(ang)]
                    )
                )
        local, closed = np.vstack(pts), False
    else:
        raise InputError(
            f"motion.path must be loop, lawnmower, line or a CSV file, not {cfg.path!r}"
        )
    return transform_points(se2(centre[0], centre[1], heading), local), closed


def read_waypoints(path: Path) -> np.ndarray:
    try:
        data = np.genfromtxt(path, delimiter=",", names=True, dtype=np.float64, ndmin=1)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: cannot read waypoints ({exc})") from exc
    names = data.dtype.names or ()
    if "x" not in names or "y" not in names:
        raise InputError(f"{path}: waypoint CSV needs a header with columns x,y")
    xy = np.column_stack([data["x"], data["y"]]).reshape(-1, 2)
    if len(xy) == 0 or not np.isfinite(xy).all():
        raise InputError(f"{path}: waypoints must be finite and at least one")
    return xy


def plan_path(cfg: MotionConfig, stand: Stand) -> PlannedPath:
    """Nominal path, shifted/pushed so it keeps `stem_clearance_m` from every stem surface."""
    clearance = cfg.stem_clearance_m
    bounds = np.asarray(stand.bounds, dtype=np.float64)
    centre0 = (
        np.asarray(cfg.centre_xy, dtype=np.float64)
        if cfg.centre_xy is not None
        else 0.5 * (bounds[:2] + bounds[2:])
    )
    if cfg.path in ("loop", "line", "lawnmower"):
        if cfg.length_m <= 0:
            raise InputError("motion.length_m must be > 0")
        heading0 = np.radians(cfg.heading_deg)
        extent = bounds[2:] - bounds[:2]
        # Candidate placements: as asked first, then small shifts and turns.
        shifts = [(0, 0), (3, 0), (-3, 0), (0, 3), (0, -3), (5, 5), (-5, 5), (5, -5), (-5, -5)]
        best = None
        for dx, dy in shifts:
            for dh in (0.0, 0.3):
                xy, closed = _nominal(cfg, centre0 + (dx, dy), heading0 + dh, extent)
                xy = _push_clear(_resample(xy, closed), closed, stand, clearance)
                c = float(stem_clearance(xy, stand).min())
                if best is None or c > best.min_clearance_m:
                    best = PlannedPath(xy, closed, c)
                if c >= 0.9 * clearance:
                    return PlannedPath(xy, closed, c)
        assert best is not None
        if _polyline_length(best.xy, best.closed) < 0.5 * cfg.length_m:
            raise ProcessingError(
                f"the {cfg.path} path shrank below half of length_m={cfg.length_m} m while "
                "keeping clear of stems; choose another centre or a longer path"
            )
        log.warning(
            "path keeps only %.2f m from the nearest stem (asked %.2f m)",
            best.min_clearance_m,
            clearance,
        )
    elif cfg.path == "station":
        way = centre0.reshape(1, 2)
        best = PlannedPath(way, False, float(stem_clearance(way, stand).min()))
    else:
        file = Path(cfg.path)
        if not file.is_file():
            raise InputError(f"motion.path {cfg.path!r}: not loop/lawnmower/line and no such file")
        way = read_waypoints(file)
        if len(way) == 1:
            c = float(stem_clearance(way, stand).min())
            best = PlannedPath(way, False, c)
        else:
            xy = _resample(way, False)
            pushed = _push_clear(xy, False, stand, clearance)
            if np.abs(pushed[[0, -1]] - xy[[0, -1]]).max() > 0.01 or len(pushed) != len(xy):
                log.info("waypoint path moved away from stems to keep %.2f m clearance", clearance)
            best = PlannedPath(pushed, False, float(stem_clearance(pushed, stand).min()))
    if best.min_clearance_m < 0.3:
        raise ProcessingError(
            f"the path passes {best.min_clearance_m:.2f} m from a stem surface; "
            "choose another centre, length or waypoints"
        )
    return best


class Trajectory:
    """T_world_sensor(t) for t in seconds since the start of the run."""

    def __init__(
        self,
        path: PlannedPath,
        cfg: MotionConfig,
        terrain: Terrain,
        rng: np.random.Generator,
        level: bool = False,
        mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        if cfg.speed_mps <= 0 and not path.static:
            raise InputError("motion.speed_mps must be > 0")
        if cfg.sensor_height_m <= 0:
            raise InputError("motion.sensor_height_m must be > 0")
        self.path, self.cfg, self.terrain, self.level = path, cfg, terrain, level
        ring = path._ring()
        self._cum = np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))]
        )
        self._ring_xy = ring
        self.length_m = float(self._cum[-1])
        self.duration_s = cfg.duration_s if path.static else self.length_m / cfg.speed_mps
        self._vib_freq = rng.uniform(0.7, 6.0, (3, 3))
        self._vib_phase = rng.uniform(0, 2 * np.pi, (3, 3))
        self._vib_zf = rng.uniform(1.0, 8.0, 2)
        self._vib_zp = rng.uniform(0, 2 * np.pi, 2)
        self._mount = Rotation.from_euler("ZYX", np.radians(np.asarray(mount_rpy_deg)[::-1]))

    def _xy_at(self, s: np.ndarray) -> np.ndarray:
        if self.path.closed:
            s = np.mod(s, self.length_m)
        else:
            s = np.clip(s, 0.0, self.length_m)
        return np.column_stack(
            [
                np.interp(s, self._cum, self._ring_xy[:, 0]),
                np.interp(s, self._cum, self._ring_xy[:, 1]),
            ]
        )

    def poses(self, t: np.ndarray) -> np.ndarray:
        """(N,) seconds since start -> (N,4,4) T_world_sensor."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        cfg = self.cfg
        if self.path.static:
            xy = np.repeat(self.path.xy, len(t), axis=0)
            yaw = np.full(len(t), np.radians(cfg.heading_deg))
        else:
            s = cfg.speed_mps * t
            xy = self._xy_at(s)
            ahead, behind = self._xy_at(s + 1.0), self._xy_at(s - 1.0)
            yaw = np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
        if self.level:
            roll = pitch = np.zeros(len(t))
            z = self.terrain.height_at(xy)
        else:
            wb, tr = cfg.footprint_m
            fwd = np.column_stack([np.cos(yaw), np.sin(yaw)])
            left = np.column_stack([-np.sin(yaw), np.cos(yaw)])
            zf = self.terrain.height_at(xy + 0.5 * wb * fwd)
            zb = self.terrain.height_at(xy - 0.5 * wb * fwd)
            zl = self.terrain.height_at(xy + 0.5 * tr * left)
            zr = self.terrain.height_at(xy - 0.5 * tr * left)
            z = 0.25 * (zf + zb + zl + zr)
            pitch = -np.arctan2(zf - zb, wb)
            roll = np.arctan2(zl - zr, tr)
            amp = np.radians(cfg.vibration_deg) / 3.0
            vib = amp * np.sin(
                2 * np.pi * self._vib_freq[None] * t[:, None, None] + self._vib_phase[None]
            ).sum(axis=2)
            roll, pitch, yaw = roll + vib[:, 0], pitch + vib[:, 1], yaw + 0.3 * vib[:, 2]
            z = z + 0.5 * cfg.vibration_z_m * np.sin(
                2 * np.pi * self._vib_zf[None] * t[:, None] + self._vib_zp[None]
            ).sum(axis=1)
        r_body = rotation_zyx(yaw, pitch, roll)
        out = np.tile(np.eye(4), (len(t), 1, 1))
        out[:, :3, :3] = r_body @ self._mount.as_matrix()
        out[:, :3, 3] = np.column_stack([xy, z]) + cfg.sensor_height_m * r_body[:, :, 2]
        return out
