"""Where a frame's stems sit against the TLS reference's stems at the TRUE pose (issue 17,
diagnosis of "its stems are not on the reference's stems" on style-b plots).

Per frame of a cached bench/tls_bench.py plot, the frame's ring stem centres are placed with
the true mid-sweep pose, the points deskewed three ways (none; the true constant velocity over
the sweep; the true continuous trajectory, per point), and compared with the reference's
stems (tls.features.reference_stems, fitted 0.5-3.5 m above the ground) and with the true
stem axis at the frame stem's own height (the simulator's lean and sweep). The printed
"stems on the reference" verdict is the pipeline's rule (_stems_on_reference).

    python bench/tls_stem_offsets.py data/cache/sim/plots/longleaf-loop-12m-b-m3-150 \
        [--frames 70:100]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from forestslam.io import read_scans, read_tum
from forestslam.odometry.deskew import deskew_points, se3_log
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.world import build_world
from forestslam.tls import TlsConfig
from forestslam.tls.features import frame_features, reference_stems
from forestslam.tls.pipeline import _frame_points_times
from forestslam.tls.runner import load_reference, with_rings


def true_axis_offset(axes, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest tree by its true axis at each point's own height -> (tree index, distance m)."""
    h = xyz[:, 2][:, None] - axes.base[None, :, 2]
    dist = np.stack(
        [
            np.linalg.norm(xyz[:, :2] - axes.axis_xy(np.full(len(xyz), i), h[:, i]), axis=1)
            for i in range(len(axes.base))
        ],
        axis=1,
    )
    return dist.argmin(axis=1), dist.min(axis=1)


def variants(world, scan, pts, times, t0: float):
    """The frame's points in the true mid-sweep sensor frame, deskewed three ways."""
    t_mid = 0.5 * float(times.max())
    T = world.trajectory.poses(np.array([scan.stamp + t_mid - t0]))[0]
    T0, T1 = world.trajectory.poses(np.array([scan.stamp, scan.stamp + 2 * t_mid]) - t0)
    twist = se3_log(np.linalg.inv(T0) @ T1) / (2 * t_mid)
    P = world.trajectory.poses(scan.stamp - t0 + times)
    w = np.einsum("nij,nj->ni", P[:, :3, :3], pts) + P[:, :3, 3]
    Ti = np.linalg.inv(T)
    return T, {
        "none": pts,
        "true_cv": deskew_points(pts, times - t_mid, twist),
        "true_continuous": w @ Ti[:3, :3].T + Ti[:3, 3],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plot", type=Path, help="a cached plot folder (with tls/ and mls/)")
    ap.add_argument("--frames", default="0:150", help="frame range first:last (exclusive)")
    args = ap.parse_args()
    cfg = TlsConfig()
    lo, hi = (int(x) for x in args.frames.split(":"))
    world = build_world(load_scenario(args.plot / "mls" / "truth" / "scenario.yaml"))
    t0, axes = world.config.motion.start_time_s, world.forest.axes
    T_world_tls = read_tum(args.plot / "tls" / "truth" / "trajectory.tum")[1][0]
    ref, _ = reference_stems(load_reference(args.plot / "tls" / "reference.laz"), cfg.features)
    ref_w = ref @ T_world_tls[:3, :3].T + T_world_tls[:3, 3]
    _, ref_axis = true_axis_offset(axes, ref_w)
    print(f"reference: {len(ref_w)} stems, off the true axis at their own height (median)")
    print(f"  {100 * np.median(ref_axis):.1f} cm")
    rows = {}
    scans = with_rings(read_scans(args.plot / "mls" / "sequence.bag"), "vlp16")
    for k, scan in enumerate(scans):
        if k >= hi:
            break
        pts, rings, times = _frame_points_times(scan, cfg)
        if k < lo or times is None:
            continue
        T, clouds = variants(world, scan, pts, times, t0)
        line = []
        for name, cloud in clouds.items():
            stems = frame_features(cloud, rings, cfg.features).stems
            if len(stems) == 0:
                line.append(f"{name} -")
                continue
            sw = stems @ T[:3, :3].T + T[:3, 3]
            to_ref = np.linalg.norm(sw[:, None, :2] - ref_w[None, :, :2], axis=2).min(axis=1)
            _, to_axis = true_axis_offset(axes, sw)
            rows.setdefault(name, []).append(np.column_stack([to_ref, to_axis]))
            hit = int((to_ref < cfg.registration.coarse_inlier_m).sum())
            need = max(cfg.registration.coarse_min_stems, int(np.ceil(0.5 * len(sw))))
            verdict = "on" if hit >= need else "OFF"
            line.append(f"{name} {hit}/{len(sw)} {verdict} med {100 * np.median(to_ref):.0f} cm")
        print(k, " | ".join(line))
    print("all frames, median / p90 cm: to the reference's stem, to the true axis at own height")
    for name, parts in rows.items():
        r = 100 * np.concatenate(parts)
        med, p90 = np.median(r, axis=0), np.percentile(r, 90, axis=0)
        print(f"  {name:16s} {med[0]:5.1f} / {p90[0]:5.1f}   {med[1]:5.1f} / {p90[1]:5.1f}")


if __name__ == "__main__":
    main()
