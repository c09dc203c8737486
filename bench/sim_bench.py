"""Simulator speed: scans per second on one core (ray casting + scan synthesis), bag writing,
and world building, for the named scenarios.

    python bench/sim_bench.py [--scenarios sample vlp16-loop ...] [--scans 60] [--rounds 3]
        [--style a|b]

CPU time (time.process_time) is printed beside wall time: on a shared machine wall time also
counts other processes. The scans are synthesized `--rounds` times: the best round is the
figure (other processes' cache traffic only ever adds CPU time), the median round is printed
beside it, with the load average. Scenarios on stands in ../shared/data are skipped when absent.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.simulate import scan_at
from forestslam.sim.world import build_world


def bench(name: str, n_scans: int, rounds: int, style: str | None = None) -> dict:
    try:
        cfg = load_scenario(name) if style is None else load_scenario(name, style=style)
        c0, w0 = time.process_time(), time.perf_counter()
        world = build_world(cfg)
    except InputError as exc:
        print(f"{name}: skipped ({exc})")
        return {}
    build_cpu, build_wall = time.process_time() - c0, time.perf_counter() - w0
    n = min(n_scans, len(world.stamps))
    scan_at(world, 0)  # warm-up
    cpus, walls = [], []
    for _ in range(max(1, rounds)):
        c0, w0 = time.process_time(), time.perf_counter()
        scans = [scan_at(world, k) for k in range(n)]
        cpus.append(time.process_time() - c0)
        walls.append(time.perf_counter() - w0)
    cpu, wall = min(cpus), walls[int(np.argmin(cpus))]
    # Ray casting alone (C++): the rays of the first scans, without noise or pose interpolation.
    pattern = world.pattern
    cast_cpu = []
    for k in range(min(n, 5)):
        poses = world.trajectory.poses(world.stamps[k] + pattern.group_time)
        origins = np.ascontiguousarray(poses[pattern.group, :3, 3])
        dirs = np.einsum("nij,nj->ni", poses[pattern.group, :3, :3], pattern.dirs)
        c0 = time.process_time()
        world.scene.cast(origins, dirs, world.profile.range_min_m, world.profile.range_max_m, 1)
        cast_cpu.append(time.process_time() - c0)
    cast_ms = float(np.mean(cast_cpu)) * 1e3
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
        "scans/s (cpu, median round)": n / float(np.median(cpus)),
        "ms/scan (cpu)": cpu / n * 1e3,
        "scans/s (wall)": n / wall,
        "cast ms": cast_ms,
        "bag ms": bag_ms,
        "build s": build_cpu,
        "build wall s": build_wall,
        "total scans": len(world.stamps),
    }


def stem_truth(name: str, style: str | None) -> dict:
    """What the stem model means for DBH: on the dense true section at 1.3 m of every tree,
    the tape truth (convex-hull girth / pi) against the area-equivalent diameter and a robust
    circle fit (forestslam._core.fit_circle, as the pipeline fits); mean difference in mm."""
    from forestslam import _core
    from forestslam.sim.forest import BREAST_HEIGHT_M, section_points

    try:
        cfg = load_scenario(name) if style is None else load_scenario(name, style=style)
        world = build_world(cfg)
    except InputError:
        return {}
    stems, trees = world.forest.stems, world.forest.trees
    at_bh = (stems[:, 9] <= BREAST_HEIGHT_M) & (stems[:, 10] > BREAST_HEIGHT_M)
    rows = stems[at_bh][np.argsort(stems[at_bh, 12], kind="stable")]
    xy = section_points(rows, cfg.seed, np.full(len(rows), BREAST_HEIGHT_M), n=720)
    area_d, fit_d = [], []
    for pts in xy:
        area = 0.5 * abs(
            np.dot(pts[:, 0], np.roll(pts[:, 1], 1)) - np.dot(pts[:, 1], np.roll(pts[:, 0], 1))
        )
        area_d.append(2 * np.sqrt(area / np.pi))
        fit_d.append(2 * _core.fit_circle(np.ascontiguousarray(pts)).radius)
    truth = trees["dbh_m"]
    return {
        "scenario": name,
        "style": cfg.style,
        "trees": len(truth),
        "area-equivalent - tape mm": 1e3 * float(np.mean(np.array(area_d) - truth)),
        "circle fit - tape mm": 1e3 * float(np.mean(np.array(fit_d) - truth)),
        "circle fit - tape mm (p5)": 1e3 * float(np.percentile(np.array(fit_d) - truth, 5)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--scenarios",
        nargs="+",
        default=["sample", "vlp16-loop", "hdl32-loop", "rsm1-robot", "tls-plot"],
    )
    ap.add_argument("--scans", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--style", default=None, help="World style a | b (default: the scenario's).")
    args = ap.parse_args()
    load_before = os.getloadavg()[0]
    rows = [r for r in (bench(s, args.scans, args.rounds, args.style) for s in args.scenarios) if r]
    header = (
        f"{'scenario':<12} {'sensor':<7} {'rays':>7} {'pts/scan':>8} {'scans/s cpu':>11} "
        f"{'(median)':>8} {'ms/scan':>8} {'(wall)':>7} {'cast ms':>8} {'bag ms':>7} "
        f"{'build s':>8} {'scans':>6}"
    )
    print(header)
    for r in rows:
        print(
            f"{r['scenario']:<12} {r['sensor']:<7} {r['rays']:>7d} {r['points']:>8.0f} "
            f"{r['scans/s (cpu)']:>11.1f} {r['scans/s (cpu, median round)']:>8.1f} "
            f"{r['ms/scan (cpu)']:>8.1f} {r['scans/s (wall)']:>7.1f} {r['cast ms']:>8.1f} "
            f"{r['bag ms']:>7.1f} {r['build s']:>8.2f} {r['total scans']:>6d}"
        )
    print(
        f"load average (1 min) {load_before:.2f} before, {os.getloadavg()[0]:.2f} after, "
        f"on {os.cpu_count()} CPUs; best of {args.rounds} rounds of up to {args.scans} scans"
    )
    print("stem model at 1.3 m (dense true section; truth = tape girth / pi), mean difference:")
    for name in args.scenarios:
        t = stem_truth(name, args.style)
        if t:
            print(
                f"  {t['scenario']:<12} style {t['style']} {t['trees']:>4d} trees: "
                f"area-equivalent {t['area-equivalent - tape mm']:+.2f} mm, circle fit "
                f"{t['circle fit - tape mm']:+.2f} mm "
                f"(5th pct {t['circle fit - tape mm (p5)']:+.2f})"
            )
    for r in rows:
        if r["sensor"] == "vlp16":
            print(
                f"VLP-16 synthesis ({r['scenario']}): {r['scans/s (cpu)']:.1f} scans/s on one "
                "core (target >= 50)"
            )


if __name__ == "__main__":
    main()
