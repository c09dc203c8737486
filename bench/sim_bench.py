"""Simulator speed: scans per second on one core (ray casting + scan synthesis), bag writing,
and world building, for the named scenarios.

    python bench/sim_bench.py [--scenarios vlp16-loop hdl32-loop rsm1-robot] [--scans 60]

CPU time (time.process_time) is printed beside wall time: on a shared machine wall time also
counts other processes. Scenarios on stands in ../shared/data fall back to `sample` when absent.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.simulate import scan_at
from forestslam.sim.world import build_world


def bench(name: str, n_scans: int) -> dict:
    try:
        cfg = load_scenario(name)
        c0, w0 = time.process_time(), time.perf_counter()
        world = build_world(cfg)
    except InputError as exc:
        print(f"{name}: skipped ({exc})")
        return {}
    build_cpu, build_wall = time.process_time() - c0, time.perf_counter() - w0
    n = min(n_scans, len(world.stamps))
    scan_at(world, 0)  # warm-up
    c0, w0 = time.process_time(), time.perf_counter()
    scans = [scan_at(world, k) for k in range(n)]
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    # Ray casting alone (C++), same rays as scan 0.
    pattern = world.pattern
    poses = world.trajectory.poses(world.stamps[0] + pattern.group_time)
    local = pattern.dirs.reshape(len(poses), -1, 3)
    dirs = np.matmul(local, poses[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
    origins = np.ascontiguousarray(poses[:, :3, 3])
    c0 = time.process_time()
    reps = 5
    for _ in range(reps):
        world.scene.cast(origins, dirs, world.profile.range_min_m, world.profile.range_max_m, 1)
    cast_ms = (time.process_time() - c0) / reps * 1e3
    from forestslam.io import write_scans

    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        write_scans(Path(tmp) / "b.bag", scans)
        bag_ms = (time.process_time() - c0) / n * 1e3
    pts = np.mean([len(s) for s in scans])
    return {
        "scenario": name,
        "sensor": world.profile.name,
        "rays": len(pattern.dirs),
        "points": pts,
        "scans/s (cpu)": n / cpu,
        "scans/s (wall)": n / wall,
        "cast ms": cast_ms,
        "bag ms": bag_ms,
        "build s": build_cpu,
        "build wall s": build_wall,
        "total scans": len(world.stamps),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--scenarios", nargs="+", default=["sample", "vlp16-loop", "hdl32-loop", "rsm1-robot"]
    )
    ap.add_argument("--scans", type=int, default=60)
    args = ap.parse_args()
    rows = [r for r in (bench(s, args.scans) for s in args.scenarios) if r]
    header = (
        f"{'scenario':<12} {'sensor':<7} {'rays':>7} {'pts/scan':>8} {'scans/s cpu':>11} "
        f"{'(wall)':>7} {'cast ms':>8} {'bag ms':>7} {'build s':>8} {'scans':>6}"
    )
    print(header)
    for r in rows:
        print(
            f"{r['scenario']:<12} {r['sensor']:<7} {r['rays']:>7d} {r['points']:>8.0f} "
            f"{r['scans/s (cpu)']:>11.1f} {r['scans/s (wall)']:>7.1f} {r['cast ms']:>8.1f} "
            f"{r['bag ms']:>7.1f} {r['build s']:>8.2f} {r['total scans']:>6d}"
        )
    vlp = [r for r in rows if r["sensor"] == "vlp16"]
    if vlp:
        best = max(r["scans/s (cpu)"] for r in vlp)
        print(f"VLP-16 synthesis: {best:.1f} scans/s on one core (target >= 50)")


if __name__ == "__main__":
    main()
