"""Does the simulator sample a stem's silhouette edges as a spinning LiDAR would? Isolated
views of the world's stems (DBH >= 10 cm) from points at breast height 2-13 m away, one
horizontal scan line at the profile's azimuth step with a random phase: `gap` is how much of
the true silhouette (2 asin(r / D)) lies beyond the outermost stem hits, in azimuth steps per
side (0.5 expected). Per range: the exact ray casts (`SimScene.cast`), with the sensor model's
dropouts (base rate, grazing loss) and with its range noise (footprint spread at grazing
incidence) plus a selection within r + 8 cm of the true centre; and the views a nearer object
cuts (left out of the others).
Usage: python bench/dbh_edge_gap.py SCENARIO.yaml [--step-deg 0.2] [--trees 40]"""

from __future__ import annotations

import argparse

import numpy as np

from forestslam.sim.scenarios import load_scenario
from forestslam.sim.world import build_world

RANGES = (2.0, 4.0, 7.0, 10.0, 13.0)


def views(world, step: float, n_trees: int, rng: np.random.Generator) -> np.ndarray:
    """Rows (range, exact gap, gap with dropouts, gap with noise and selection, occluded)."""
    tr, noise = world.forest.trees, world.noise
    big = np.nonzero(tr["dbh_m"] >= 0.1)[0]
    rows = []
    for k in rng.choice(big, min(n_trees, len(big)), replace=False):
        c, r = np.array([tr["x"][k], tr["y"][k]]), tr["dbh_m"][k] / 2
        for dist in RANGES:
            for _ in range(6):
                ang = rng.uniform(0, 2 * np.pi)
                o = np.array([*(c + dist * np.array([np.cos(ang), np.sin(ang)])), 0.0])
                o[2] = tr["z_ground"][k] + 1.3
                half = np.arcsin(min(r / dist, 0.99)) + 4 * step
                az = np.arange(ang + np.pi - half + rng.uniform(0, step), ang + np.pi + half, step)
                dirs = np.c_[np.cos(az), np.sin(az), np.zeros_like(az)]
                res = world.scene.cast(o[None, :], dirs, 0.0, 100.0, 1)
                on = (res.surface == 2) & (res.object == k)
                if on.sum() < 2:
                    continue
                nearer = np.isfinite(res.range) & ~on & (np.nan_to_num(res.range, nan=1e9) < dist)
                a, tw = az[on] - ang - np.pi, 2 * np.arcsin(min(r / dist, 0.99))
                cosi = res.cos_incidence[on]
                keep_p = (1 - noise.dropout_rate) * np.where(
                    cosi < noise.grazing_cos, np.maximum(cosi, 0) / noise.grazing_cos, 1.0
                )
                c_cl = np.clip(cosi, 0.0995, 1.0)
                sigma = np.hypot(
                    noise.range_noise_m,
                    0.5e-3
                    * noise.beam_divergence_mrad
                    * res.range[on]
                    * np.sqrt(1 - c_cl**2)
                    / c_cl,
                )
                g_drop, g_sel = [], []
                for _ in range(20):
                    kept = rng.uniform(size=len(a)) < keep_p
                    p = (
                        o[:2]
                        + (res.range[on] + sigma * rng.standard_normal(len(a)))[:, None]
                        * (dirs[on][:, :2])
                    )
                    sel = kept & (np.linalg.norm(p - c, axis=1) <= r + 0.08)
                    for m, out in ((kept, g_drop), (sel, g_sel)):
                        if m.sum() >= 2:
                            out.append((tw - np.ptp(a[m])) / (2 * step))
                rows.append(
                    (
                        dist,
                        (tw - np.ptp(a)) / (2 * step),
                        np.mean(g_drop) if g_drop else np.nan,
                        np.mean(g_sel) if g_sel else np.nan,
                        float(nearer.any()),
                    )
                )
    return np.asarray(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario")
    ap.add_argument("--step-deg", type=float, default=0.2)
    ap.add_argument("--trees", type=int, default=40)
    args = ap.parse_args()
    world = build_world(load_scenario(args.scenario))
    rows = views(world, np.deg2rad(args.step_deg), args.trees, np.random.default_rng(0))
    print(f"{args.scenario}: {world.noise}")
    print("range m  views  exact  +dropout  +noise,select  | cut views: share, exact gap")
    for dist in RANGES:
        m = rows[:, 0] == dist
        clean, cut = m & (rows[:, 4] == 0), m & (rows[:, 4] == 1)
        print(
            f"{dist:6.1f}  {clean.sum():5d}  {np.nanmean(rows[clean, 1]):+.3f}"
            f"  {np.nanmean(rows[clean, 2]):+.3f}    {np.nanmean(rows[clean, 3]):+.3f}"
            f"         | {cut.mean() / max(m.mean(), 1e-9):.2f}, "
            f"{np.nanmean(rows[cut, 1]) if cut.any() else np.nan:+.2f}"
        )


if __name__ == "__main__":
    main()
