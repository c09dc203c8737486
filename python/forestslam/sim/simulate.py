"""Run a scenario: write the sequence (or the TLS reference) and its ground truth."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from forestslam.config_utils import to_dict
from forestslam.errors import InputError
from forestslam.io import Scan
from forestslam.io.atomic import atomic_write_text
from forestslam.sim.config import SimConfig
from forestslam.sim.scanner import synthesize_scan
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.world import World, build_world

log = logging.getLogger(__name__)
FORMATS = {"bag": ".bag", "mcap": ".mcap"}
# Version of the simulator's world and sensor models: caches of simulated sequences key on it.
# 2: shaped stems (polygon, lobes, flare, sweep), girth truth DBH, material intensity, sensor
# noise table, world styles.
MODEL_VERSION = 2


def scan_at(world: World, k: int, labels: bool = False):
    """Scan k of the run (deterministic: depends only on the scenario and k). labels=True also
    returns the per-point surface class and object (see synthesize_scan)."""
    t0 = float(world.stamps[k])
    knot_time = world.pattern.group_time[world.pattern.knot_groups]
    poses = world.trajectory.poses(t0 + knot_time)
    rng = np.random.default_rng([int(world.config.seed), 501, k])
    stamp = world.config.motion.start_time_s + t0
    return synthesize_scan(
        world.scene,
        world.pattern,
        poses,
        world.scan_model,
        stamp,
        rng,
        world.scan_seed(k),
        labels=labels,
        pose_times=knot_time,
    )


def iter_scans(world: World, progress: bool = False) -> Iterator[Scan]:
    indices = range(len(world.stamps))
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc=f"simulate {world.config.name}", unit="scan")
    for k in indices:
        yield scan_at(world, k)


def truth_poses(world: World) -> tuple[np.ndarray, np.ndarray]:
    """Scan stamps (S,) and T_world_sensor (S,4,4) at each stamp (sweep start)."""
    stamps = world.config.motion.start_time_s + world.stamps
    return stamps, world.trajectory.poses(world.stamps)


def _derived(world: World) -> dict[str, Any]:
    import forestslam

    return {
        "forestslam_version": getattr(forestslam, "__version__", "unknown"),
        "sim_model_version": MODEL_VERSION,
        "sensor_profile": world.profile.to_dict(),
        "scans": int(len(world.stamps)),
        "duration_s": round(float(len(world.stamps) / world.profile.rate_hz), 6)
        if world.profile.rate_hz > 0
        else 0.0,
        "path_length_m": round(float(world.trajectory.length_m), 4),
        "path_min_stem_clearance_m": round(float(world.path.min_clearance_m), 4),
        "stand_bounds_m": [round(float(v), 4) for v in world.stand.bounds],
        "terrain_origin_cell_m": [world.terrain.x0, world.terrain.y0, world.terrain.cell],
        "objects": world.forest.counts(),
        "sensor_noise": dataclasses.asdict(world.noise),
        "truth_dbh": "convex-hull girth / pi of the horizontal stem section 1.3 m above "
        "z_ground (= mean caliper diameter over all directions)",
    }


def write_truth(world: World, out_dir: Path) -> None:
    from forestslam.io import write_trees_csv, write_tum

    truth = out_dir / "truth"
    truth.mkdir(parents=True, exist_ok=True)
    stamps, poses = truth_poses(world)
    write_tum(truth / "trajectory.tum", stamps, poses)
    write_trees_csv(truth / "trees.csv", world.forest.trees)
    doc = to_dict(world.config)
    doc["derived"] = _derived(world)
    atomic_write_text(truth / "scenario.yaml", yaml.safe_dump(doc, sort_keys=False))


def simulate(
    scenario: str | Path | SimConfig | None,
    out_dir: str | Path,
    progress: bool = False,
    **overrides,
) -> Path:
    """Simulate a named scenario / YAML file / SimConfig with overrides (see load_scenario) into
    out_dir: sequence.bag|.mcap (or reference.laz for the tls profile), truth/trajectory.tum,
    truth/trees.csv, truth/scenario.yaml, and preview.png when asked. Returns out_dir."""
    cfg = load_scenario(scenario, **overrides)
    if cfg.output.format not in FORMATS:
        raise InputError(
            f"output.format must be one of {', '.join(FORMATS)}, not {cfg.output.format!r}"
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    world = build_world(cfg)
    write_truth(world, out_dir)
    preview_scan = None
    if world.profile.kind == "tls":
        from forestslam.io import write_cloud

        scan = scan_at(world, 0)
        write_cloud(out_dir / "reference.laz", scan.points, scan.intensity)
        preview_scan = scan
        log.info("TLS station: %d points -> %s", len(scan), out_dir / "reference.laz")
    else:
        from forestslam.io import write_scans

        target = out_dir / f"sequence{FORMATS[cfg.output.format]}"
        n = write_scans(
            target,
            iter_scans(world, progress),
            topic=cfg.output.topic,
            frame_id=cfg.output.frame_id,
        )
        log.info("%d scans -> %s", n, target)
    if cfg.output.preview:
        from forestslam.sim.preview import write_preview

        k = len(world.stamps) // 2
        write_preview(
            world,
            preview_scan if preview_scan is not None else scan_at(world, k),
            k,
            out_dir / "preview.png",
        )
    return out_dir
