"""DBH bench (issue 15): where a DBH bias comes from, stage by stage and factor by factor.

Stem worlds from forestslam.perception.synthetic_stems (not forestslam.sim): two styles, `round`
(analytic cylinders, flat intensity: what the project's simulator showed) and `rough` (7-14-gons
with 5 mm bark noise, 0-10 % ovality, a Lambertian intensity model whose unknown gain lets the
profile's threshold cut into the bark), plus `rough-m`: the rough stems under a second intensity
model not derived from the threshold (per-material log-normal, see synthetic_stems). A sensor
drives a 40 m lane at 1 m/s, 10 Hz, with perfect poses (so only DBH is measured); each scan
goes through `forestslam.perception.detect`.

1. Per scan, each DBH stage against truth (stems within 15 m): silhouette, band circle (the
   orthogonal fit, and the range-model fit the chain now uses), SAC cylinder, the chosen DBH;
   range noise 1 / 2 / 3 cm; intensity filter on / off.
2. Map DBH (mapping.TreeMap, windows of accumulated band points): orthogonal vs range-model
   fit, fusion window 5 / 25 / 100 scans, inlier gate 1.5 / 3 / 6 cm, one-sided (the trees
   passed on one side only: lane at the world's edge) vs both sides, by ovality / polygon.
   dbh_std_m calibration: the share of trees whose truth lies within +-1 sigma.
3. Gupta et al. (Sensors 2023) protocol side by side: single scan vs accumulated 25 scans
   (SAC cylinder / band circle) vs full-map DBH; adaptive vs fixed-radius normal filter (trees
   found); the paper's figures printed beside.

Usage: python bench/dbh_bench.py [--worlds 2] [--first-world 0] [--noise 0.01,0.02,0.03]
         [--sensor vlp16] [--quick]
(--quick --first-world 1: the quick figures on a second, independent world.)
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from forestslam.mapping.config import MappingConfig
from forestslam.mapping.tree_map import TreeMap, fit_band_circle
from forestslam.perception import PerceptionConfig, detect, estimate_diameter
from forestslam.perception.synthetic_stems import (
    ROUGH,
    ROUGH_MATERIAL,
    ROUND,
    StemStyle,
    make_world,
    scan_stems,
)

LANE_M = 40.0
RANGE_M = 15.0
GATE_M = 0.6
PAPER = {
    "single": 6.3,
    "acc_cylinder": 5.9,
    "acc_band": 4.4,
    "map": "4.3-4.4",
    "adaptive_gain": "+13 %",
}


@dataclasses.dataclass
class Run:
    """Detections of one drive: per scan the sensor xy, the stems and their truth index."""

    style: StemStyle
    noise: float
    world: list
    sensor_xy: list
    stems: list
    truth_idx: list

    @property
    def truth_xy(self) -> np.ndarray:
        return np.array([[s.x, s.y] for s in self.world])

    @property
    def truth_dbh(self) -> np.ndarray:
        return np.array([s.dbh for s in self.world])


def drive(
    style, noise, seed, sensor, config, step_m=0.1, one_sided=False, footprint_rad=0.0
) -> Run:
    world = make_world(style, seed)
    if one_sided:  # trees on one side of the lane only: each is seen from one side
        world = [s for s in world if s.y > 0]
    gain = np.random.default_rng(seed + 7).uniform(*style.gain)
    txy = np.array([[s.x, s.y] for s in world])
    run = Run(style, noise, world, [], [], [])
    for i, x in enumerate(np.arange(0.0, LANE_M, step_m)):
        sxy = np.array([x, 0.0])
        scan = scan_stems(
            world,
            sxy,
            style,
            sensor,
            noise_m=noise,
            seed=seed * 10000 + i,
            gain=gain,
            footprint_rad=footprint_rad,
        )
        stems = detect(scan, sensor, config)
        idx = np.full(len(stems), -1)
        for k in range(len(stems)):
            d = np.linalg.norm(txy - sxy - stems.mean[k, :2], axis=1)
            if d.min() < GATE_M:
                idx[k] = int(np.argmin(d))
        run.sensor_xy.append(sxy)
        run.stems.append(stems)
        run.truth_idx.append(idx)
    return run


def stats(err_cm) -> str:
    e = np.asarray(err_cm, dtype=float)
    e = e[np.isfinite(e)]
    if len(e) == 0:
        return f"{'-':>5} {'-':>7} {'-':>6}"
    return f"{len(e):5d} {e.mean():+7.2f} {np.abs(e).mean():6.2f}"


HEADER = f"{'n':>5} {'bias':>7} {'MAE':>6}  (cm)"


# ---- 1. per-scan stages ----


def scan_stage_errors(runs) -> dict[str, list]:
    """Per-scan DBH error (cm) of each stage, stems within RANGE_M."""
    out = {k: [] for k in ("silhouette", "circle", "circle_ortho", "cylinder", "chosen")}
    for run in runs:
        tdbh = run.truth_dbh
        for sxy, stems, idx in zip(run.sensor_xy, run.stems, run.truth_idx, strict=True):
            for k in np.nonzero(idx >= 0)[0]:
                j = idx[k]
                if np.linalg.norm(run.truth_xy[j] - sxy) > RANGE_M:
                    continue
                d = stems.diameters[k]
                for m in ("silhouette", "circle", "cylinder"):
                    if getattr(d, m).valid:
                        out[m].append(100 * (2 * getattr(d, m).radius - tdbh[j]))
                out["chosen"].append(100 * (stems.dbh[k] - tdbh[j]))
                pts = stems.points[k]
                h = pts[:, 2] - stems.base_z[k]
                band = pts[(h >= 1.15) & (h <= 1.45)]
                fit = fit_band_circle(band[:, :2], ORTHO_BAND) if len(band) >= 5 else None
                if fit is not None:
                    out["circle_ortho"].append(100 * (2 * fit.radius - tdbh[j]))
    return out


ORTHO_BAND = MappingConfig(dbh_min_points=5, dbh_min_arc_coverage=0.1, dbh_max_rms_m=0.05)


# ---- 2. map DBH ----


def map_dbh(run: Run, cfg: MappingConfig, rays: bool = True, lateral_m: float | None = None):
    """(truth dbh, map dbh, dbh_std, carries) of every truth tree passed within RANGE_M."""
    tm = TreeMap(cfg)
    if not rays:  # the orthogonal fit: no view origins

        def ortho_fit(tree):
            tree.origins = []
            pts = np.concatenate(tree.band)
            tree.band, tree.n_band_scans = [], 0
            tm.n_fits += 1
            fit = fit_band_circle(pts[:, :2], cfg)
            if fit is not None:
                tree.measurements.append((2 * fit.radius, fit.inliers * fit.arc_coverage**2))

        tm._fit = ortho_fit
    for i, (sxy, stems, idx) in enumerate(
        zip(run.sensor_xy, run.stems, run.truth_idx, strict=True)
    ):
        T = np.eye(4)
        T[:2, 3] = sxy
        tm.add(i, T, idx, stems.points, stems.base_z, stems.z, stems.dbh)
        tm.flush(i)
    tm.flush()
    rows = []
    for j, s in enumerate(run.world):
        if not (0 <= s.x <= LANE_M and abs(s.y) <= RANGE_M) or j not in tm.trees:
            continue
        d, sd, _ = tm.dbh(j)
        rows.append((s.dbh, d, sd))
    return np.array(rows).reshape(-1, 3)


def map_line(rows) -> str:
    t, d, sd = rows.T
    ok = np.isfinite(d)
    e = 100 * (d - t)
    within = np.abs(d - t)[ok & np.isfinite(sd)] <= sd[ok & np.isfinite(sd)]
    cal = f"{within.mean():5.2f}" if len(within) else "  -  "
    return f"{stats(e)}  carry {ok.mean():5.2f}  1-sigma {cal}"


# ---- 3. Gupta protocol ----


def accumulated_dbh(run: Run, window: int = 25):
    """Per tree and window of `window` scans: DBH of the accumulated stem points by the SAC
    cylinder and by the band circle (estimate_diameter on the map-frame cloud)."""
    cfg = PerceptionConfig()
    cfg.diameter.fit_all = True
    cyl, band = [], []
    per_tree: dict[int, list] = {}
    for sxy, stems, idx in zip(run.sensor_xy, run.stems, run.truth_idx, strict=True):
        for k in np.nonzero(idx >= 0)[0]:
            per_tree.setdefault(int(idx[k]), []).append(
                (stems.points[k] + np.r_[sxy, 0.0], stems.base_z[k])
            )
    for j, obs in per_tree.items():
        for w0 in range(0, len(obs) - window + 1, window):
            chunk = obs[w0 : w0 + window]
            pts = np.concatenate([p for p, _ in chunk])
            base = float(np.median([b for _, b in chunk]))
            c = run.truth_xy[j]
            normals = np.c_[pts[:, :2] - c, np.zeros(len(pts))]
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
            d = estimate_diameter(pts, base, normals, cfg)
            truth = run.truth_dbh[j]
            if d.cylinder.valid:
                cyl.append(100 * (2 * d.cylinder.radius - truth))
            if d.circle.valid:
                band.append(100 * (2 * d.circle.radius - truth))
    return cyl, band


def trees_found(style, seed, sensor, adaptive: bool, n_scans: int = 10) -> int:
    cfg = PerceptionConfig()
    cfg.filter.adaptive = adaptive
    world = make_world(style, seed)
    txy = np.array([[s.x, s.y] for s in world])
    found = 0
    for i, x in enumerate(np.linspace(0, LANE_M, n_scans)):
        sxy = np.array([x, 0.0])
        stems = detect(scan_stems(world, sxy, style, sensor, seed=i), sensor, cfg)
        near = np.linalg.norm(txy - sxy, axis=1) <= RANGE_M
        for j in np.nonzero(near)[0]:
            if len(stems) and np.linalg.norm(stems.xy - (txy[j] - sxy), axis=1).min() < GATE_M:
                found += 1
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", type=int, default=2, help="worlds (seeds) per style")
    ap.add_argument("--noise", default="0.01,0.02,0.03", help="range noise levels (m)")
    ap.add_argument("--sensor", default="vlp16")
    ap.add_argument("--first-world", type=int, default=0, help="seed of the first world")
    ap.add_argument("--quick", action="store_true", help="one world, 3 cm noise only")
    args = ap.parse_args()
    noises = [0.03] if args.quick else [float(x) for x in args.noise.split(",")]
    seeds = range(args.first_world, args.first_world + (1 if args.quick else args.worlds))
    t0 = time.process_time()
    config = PerceptionConfig()
    config.diameter.fit_all = True
    runs = {}
    for style in (ROUND, ROUGH, ROUGH_MATERIAL):
        for noise in noises:
            runs[style.name, noise] = [drive(style, noise, s, args.sensor, config) for s in seeds]
    print(
        f"# DBH bench, {args.sensor}, worlds {list(seeds)}, "
        f"{sum(len(r.stems) for v in runs.values() for r in v)} scans detected"
    )

    print(f"\n## 1. Per-scan DBH by stage (stems within {RANGE_M:.0f} m)")
    print(f"{'style':6} {'noise':>5} {'stage':13} {HEADER}")
    for (name, noise), rs in runs.items():
        for stage, e in scan_stage_errors(rs).items():
            print(f"{name:6} {100 * noise:4.0f}c {stage:13} {stats(e)}")
    # The same drives with the other setting of intensity_as_evidence (the removed returns as
    # evidence per cluster, detector.cpp): the chosen DBH beside the default's.
    other = dataclasses.replace(config, intensity_as_evidence=not config.intensity_as_evidence)
    for style in (ROUND, ROUGH, ROUGH_MATERIAL):
        rs = [drive(style, noises[-1], s, args.sensor, other) for s in seeds]
        label = f"chosen, evidence {'on' if other.intensity_as_evidence else 'off'}"
        e = scan_stage_errors(rs)["chosen"]
        print(f"{style.name:6} {100 * noises[-1]:4.0f}c {label:13} {stats(e)}")
    # The filter off, and the removed returns as evidence per cluster (intensity_as_evidence),
    # beside the filter before the clustering (the default), all at 1 m steps.
    variants = (
        ("chosen, filter (1 m steps)", config),
        ("chosen, no intensity filter", dataclasses.replace(config, intensity_filter=False)),
        ("chosen, intensity evidence", dataclasses.replace(config, intensity_as_evidence=True)),
    )
    for style in (ROUND, ROUGH, ROUGH_MATERIAL):
        for label, cfg in variants:
            rs = [drive(style, noises[-1], s, args.sensor, cfg, step_m=1.0) for s in seeds]
            e = scan_stage_errors(rs)
            print(f"{style.name:6} {100 * noises[-1]:4.0f}c {label:28} {stats(e['chosen'])}")
    # Beam footprint: a VLP-16 beam diverges ~3 mrad; returns from partly hit edges widen a
    # silhouette by up to range x divergence (worst case: any part of the footprint returns).
    for style in (ROUND, ROUGH_MATERIAL):
        rs = [
            drive(style, noises[-1], s, args.sensor, config, step_m=1.0, footprint_rad=1.5e-3)
            for s in seeds
        ]
        e = scan_stage_errors(rs)
        for stage in ("silhouette", "chosen"):
            label = f"{stage}, 3 mrad footprint"
            print(f"{style.name:6} {100 * noises[-1]:4.0f}c {label:28} {stats(e[stage])}")

    print("\n## 2. Map DBH (perfect poses), TreeMap windows")
    print(f"{'style':6} {'noise':>5} {'variant':30} {HEADER}")
    base = MappingConfig()
    for (name, noise), rs in runs.items():
        variants = [("orthogonal fit (before)", base, False), ("range-model fit", base, True)]
        if noise == noises[-1]:
            variants += [
                (
                    "rays, window 5",
                    dataclasses.replace(base, dbh_window_scans=5, dbh_min_window_scans=3),
                    True,
                ),
                ("rays, window 100", dataclasses.replace(base, dbh_window_scans=100), True),
                ("rays, gate 1.5 cm", dataclasses.replace(base, circle_inlier_m=0.015), True),
                (
                    "rays, gate 6 cm",
                    dataclasses.replace(base, circle_inlier_m=0.06, dbh_max_rms_m=0.06),
                    True,
                ),
                ("ortho, gate 1.5 cm", dataclasses.replace(base, circle_inlier_m=0.015), False),
                (
                    "ortho, gate 6 cm",
                    dataclasses.replace(base, circle_inlier_m=0.06, dbh_max_rms_m=0.06),
                    False,
                ),
            ]
        for label, cfg, rays in variants:
            rows = np.concatenate([map_dbh(r, cfg, rays) for r in rs])
            print(f"{name:6} {100 * noise:4.0f}c {label:30} {map_line(rows)}")
    # One-sided views: the trees on one side of the lane only.
    for style in (ROUND, ROUGH):
        rs = [
            drive(style, noises[-1], s, args.sensor, PerceptionConfig(), one_sided=True)
            for s in seeds
        ]
        for label, rays in (("one-sided, orthogonal", False), ("one-sided, range model", True)):
            rows = np.concatenate([map_dbh(r, base, rays) for r in rs])
            print(f"{style.name:6} {100 * noises[-1]:4.0f}c {label:30} {map_line(rows)}")
    # Ovality and polygon size on the rough style (range model).
    rough = runs["rough", noises[-1]]
    print(f"rough: map error by cross-section (range model, noise {100 * noises[-1]:.0f} cm)")
    ov_rows = []
    for r in rough:
        rows = map_dbh(r, base, True)
        kept = [s for s in r.world if 0 <= s.x <= LANE_M and abs(s.y) <= RANGE_M]
        for s, (t, d, _) in zip(kept, rows, strict=False):
            v = s.polygon
            rr = np.linalg.norm(v, axis=1)
            ov_rows.append((len(v), (rr.max() - rr.min()) / (rr.max() + rr.min()), 100 * (d - t)))
    ov = np.array(ov_rows)
    for lo, hi in ((0, 0.04), (0.04, 0.07), (0.07, 1)):
        m = (ov[:, 1] >= lo) & (ov[:, 1] < hi)
        print(f"  ovality+bark {lo:.2f}-{hi:.2f}: {stats(ov[m, 2])}")
    for lo, hi in ((7, 10), (10, 15)):
        m = (ov[:, 0] >= lo) & (ov[:, 0] < hi)
        print(f"  {lo}-{hi - 1} sides:          {stats(ov[m, 2])}")

    print("\n## 3. Gupta et al. protocol (MAE cm; the paper's figures beside)")
    for (name, noise), rs in runs.items():
        if noise != noises[-1]:
            continue
        single = scan_stage_errors(rs)["chosen"]
        cyl, band = [], []
        for r in rs:
            c, b = accumulated_dbh(r)
            cyl += c
            band += b
        full = dataclasses.replace(base, dbh_window_scans=10**6)
        fmap = np.concatenate([map_dbh(r, full, True) for r in rs])
        wmap = np.concatenate([map_dbh(r, base, True) for r in rs])
        print(f"{name} ({100 * noise:.0f} cm noise):")
        print(f"  single scan            {stats(single)}   paper MAE {PAPER['single']}")
        print(f"  accumulated, cylinder  {stats(cyl)}   paper MAE {PAPER['acc_cylinder']}")
        print(f"  accumulated, band      {stats(band)}   paper MAE {PAPER['acc_band']}")
        print(f"  map, windows of 25     {map_line(wmap)}   paper MAE {PAPER['map']}")
        print(f"  map, one fit per tree  {map_line(fmap)}")
    for style in (ROUND, ROUGH):
        a = sum(trees_found(style, s, args.sensor, True) for s in seeds)
        f = sum(trees_found(style, s, args.sensor, False) for s in seeds)
        print(
            f"  {style.name}: trees found adaptive {a} vs fixed radius {f} "
            f"({100 * (a / max(f, 1) - 1):+.0f} %; paper {PAPER['adaptive_gain']})"
        )
    print(f"\nCPU {time.process_time() - t0:.0f} s")


if __name__ == "__main__":
    main()
