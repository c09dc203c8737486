"""Circle-fit speed bench (issue 18): `fit_circle_rays` of this tree against a baseline build, on
the same stem bands, with the largest difference of their results.

The bands are breast-height arcs as a LiDAR sees them (seeded): one side of a stem of 8-60 cm
diameter at 2-25 m, range noise along the beams, a few points of clutter, 4 to 1,500 points
(single scans have few, the tree map's windows of accumulated scans many). Each side runs in
its own process pinned to one core and fits every band; the figures are CPU time per call and
max |difference| of centre, radius and inlier count (0 when the two fits are bit-identical).

    python bench/circle_fit_bench.py [--baseline SOURCE_TREE] [--bands 3000] [--repeat 3]

SOURCE_TREE is a source tree with a built `build/py/python` (default /work/wt/base).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def bands(count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """(xy (N,2), origins (N,2)) per band; the sensor at the origin."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        n = int(np.clip(rng.lognormal(np.log(14), 1.0), 4, 1500))
        r = rng.uniform(0.04, 0.30)
        dist = rng.uniform(2.0, 25.0)
        bearing = rng.uniform(-np.pi, np.pi)
        centre = dist * np.array([np.cos(bearing), np.sin(bearing)])
        half = np.arcsin(min(1.0, r / dist)) * rng.uniform(0.6, 1.0)
        az = bearing + rng.uniform(-half, half, n)
        u = np.column_stack([np.cos(az), np.sin(az)])
        b = u @ centre  # near hit of each beam on the circle
        disc = np.maximum(b**2 - (dist**2 - r**2), 0.0)
        rng_m = b - np.sqrt(disc) + rng.normal(0, rng.uniform(0.005, 0.03), n)
        xy = u * rng_m[:, None]
        clutter = rng.random(n) < 0.05
        xy[clutter] += rng.normal(0, 0.3, (clutter.sum(), 2))
        out.append((xy, np.zeros_like(xy)))
    return out


def child(count: int, repeat: int, out: Path) -> None:
    from forestslam import _core

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    data = bands(count)
    cfg = _core.CircleFitConfig()
    cfg.min_radius_m, cfg.max_radius_m = 0.02, 0.6
    best = float("inf")
    for _ in range(repeat):
        c = time.process_time()
        fits = [_core.fit_circle_rays(xy, o, cfg) for xy, o in data]
        best = min(best, time.process_time() - c)
    rows = [
        [f.valid, *(f.centre if f.valid else (np.nan, np.nan)), f.radius, f.inliers] for f in fits
    ]
    np.save(out, np.array(rows, dtype=np.float64))
    print(json.dumps({"us_per_call": best / count * 1e6}))


def run_side(tree: Path, count: int, repeat: int, out: Path) -> float:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    env["PYTHONPATH"] = f"{tree / 'python'}:{tree / 'build' / 'py' / 'python'}"
    cmd = [sys.executable, __file__, "--child", str(count), str(repeat), str(out)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])["us_per_call"]


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(int(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4]))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, default=Path("/work/wt/base"))
    ap.add_argument("--bands", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    tmp = REPO / "data" / "cache" / "bench-speed" / "circle-fit"
    tmp.mkdir(parents=True, exist_ok=True)
    us = {}
    for name, tree in (("after", REPO), ("before", args.baseline)):
        us[name] = run_side(tree, args.bands, args.repeat, tmp / f"{name}.npy")
    a, b = np.load(tmp / "after.npy"), np.load(tmp / "before.npy")
    same_valid = np.array_equal(a[:, 0], b[:, 0])
    both = (a[:, 0] == 1) & (b[:, 0] == 1)
    diff = np.abs(a[both, 1:] - b[both, 1:]).max(axis=0) if both.any() else np.zeros(4)
    print(f"{args.bands} bands, {int(both.sum())} fitted by both")
    print(
        f"  us per call: after {us['after']:.1f}, before {us['before']:.1f}, "
        f"ratio {us['after'] / us['before']:.2f}"
    )
    print(
        f"  same validity: {same_valid}; max |diff| centre x {diff[0]:.3g} m, "
        f"y {diff[1]:.3g} m, radius {diff[2]:.3g} m, inliers {diff[3]:.0f}"
    )


if __name__ == "__main__":
    main()
