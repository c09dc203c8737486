"""All a run needs before its first scan: stand, path, terrain, forest, ray caster, motion."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from forestslam.errors import InputError
from forestslam.sensors import SensorProfile, load_profile
from forestslam.sim.config import SimConfig
from forestslam.sim.forest import Forest, build_forest
from forestslam.sim.motion import PlannedPath, Trajectory, plan_path
from forestslam.sim.scanner import ScanPattern, make_pattern
from forestslam.sim.sensor_model import SensorNoise, scan_model, sensor_noise
from forestslam.sim.stand import Stand, load_stand
from forestslam.sim.terrain import Terrain, make_terrain

log = logging.getLogger(__name__)


@dataclass
class World:
    config: SimConfig
    profile: SensorProfile
    stand: Stand
    path: PlannedPath
    terrain: Terrain
    forest: Forest
    scene: object  # forestslam._core.SimScene
    trajectory: Trajectory
    pattern: ScanPattern
    stamps: np.ndarray  # (S,) scan stamps, seconds
    noise: SensorNoise  # range noise and dropouts of the simulated sensor
    scan_model: Any  # forestslam._core.ScanModel for the C++ synthesis (sensor_model.scan_model)

    def scan_seed(self, k: int) -> int:
        return (int(self.config.seed) * 1_000_003 + 7919 * k + 1) % (2**63)


def scan_times(profile: SensorProfile, trajectory: Trajectory, max_scans: int | None) -> np.ndarray:
    """Sweep start times (seconds since the run start) of every complete sweep."""
    if profile.kind == "tls" or profile.rate_hz <= 0:
        return np.zeros(1)
    period = 1.0 / profile.rate_hz
    n = max(1, int(np.floor(trajectory.duration_s / period + 1e-9)))
    if trajectory.path.closed:
        n = max(1, n)  # the last sweep ends where the loop closes
    if max_scans is not None:
        n = min(n, int(max_scans))
    return np.arange(n) * period


def build_world(cfg: SimConfig) -> World:
    from forestslam import _core

    profile = load_profile(cfg.sensor.profile)
    if profile.kind == "map":
        raise InputError("sensor 'map' is not a scanner; choose vlp16, hdl32, os1-64, rs-m1 or tls")
    seed = int(cfg.seed)
    noise = sensor_noise(profile, cfg.sensor)
    model = scan_model(profile, noise, cfg.intensity, object_seed=seed * 1_000_003 + 601)
    stand = load_stand(cfg.stand, seed=seed)
    path = plan_path(cfg.motion, stand)
    if profile.kind == "tls" and not path.static:
        raise InputError("the tls profile needs a static station: a waypoint CSV with one row")
    clear_xy = path.xy
    if cfg.clutter.keep_clear_scenario:
        from forestslam.sim.scenarios import load_scenario

        other = load_scenario(cfg.clutter.keep_clear_scenario)
        clear_xy = np.vstack([path.xy, plan_path(other.motion, stand).xy])
    pts = np.vstack([stand.xy.reshape(-1, 2), clear_xy])
    b = stand.bounds
    extent = (
        min(b[0], pts[:, 0].min()),
        min(b[1], pts[:, 1].min()),
        max(b[2], pts[:, 0].max()),
        max(b[3], pts[:, 1].max()),
    )
    terrain = make_terrain(cfg.terrain, extent, np.random.default_rng([seed, 301]))
    forest = build_forest(stand, terrain, cfg.stems, cfg.clutter, clear_xy, seed)
    scene = _core.SimScene(
        terrain.x0,
        terrain.y0,
        terrain.cell,
        terrain.z,
        forest.stems,
        forest.cylinders,
        forest.foliage,
        seed=seed,
    )
    trajectory = Trajectory(
        path,
        cfg.motion,
        terrain,
        np.random.default_rng([seed, 401]),
        level=profile.kind == "tls",
        mount_rpy_deg=tuple(cfg.sensor.mount_rpy_deg),
    )
    pattern = make_pattern(profile)
    stamps = scan_times(profile, trajectory, cfg.motion.max_scans)
    log.info(
        "world: %d trees, path %.1f m (clearance %.2f m), %d scans of %s",
        len(stand),
        trajectory.length_m,
        path.min_clearance_m,
        len(stamps),
        profile.name,
    )
    return World(
        cfg, profile, stand, path, terrain, forest, scene, trajectory, pattern, stamps, noise, model
    )
