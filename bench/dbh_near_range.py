"""Why single-scan silhouettes come out small near the sensor: per-scan silhouette DBH against
truth, binned by range, from the detector and from the same silhouette formula applied to
(a) the detector's stem points, (b) every raw return on the stem (no intensity filter, no
normal filter, no clustering), (c) the raw returns that pass the intensity filter, (c2) those
thinned like the normal filter (first point per voxel), and with the
line's nearest range replaced by (d) the median range of the points facing the sensor, (e) the
true centre distance minus the true radius. `gap` is how much of the true silhouette (2 asin
(r / D), true r and D) lies beyond the outermost hits of a scan line, in azimuth steps per side
(0.5 if the edges are sampled as the formula assumes), over all lines and split into lines
whose edge is cut by a nearer return of the same scan line within 1.5 steps (occluded: a
branch, foliage or another stem in front) and the others (clean). Poses and stems from the
truth.
Usage: python bench/dbh_near_range.py SIM_DIR [SIM_DIR ...] [--scans 40] [--min-dbh 0.1]
[--true-centre]"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from forestslam.geometry import transform_points
from forestslam.io import read_scans, read_trees_csv, read_tum
from forestslam.perception import PerceptionConfig, detect
from forestslam.sensors import load_profile

BINS = (0.0, 3.0, 6.0, 9.0, 12.0, 15.0)
VARIANTS = (
    "detector",
    "stem_pts",
    "raw_all",
    "raw_thr",
    "raw_voxel",
    "raw_medrange",
    "raw_truerange",
)


def first_per_voxel(p: np.ndarray, voxel: float) -> np.ndarray:
    """Rows of p kept by the normal filter's thinning: the first point (scan order) per voxel."""
    _, first = np.unique(np.floor(p / voxel).astype(np.int64), axis=0, return_index=True)
    return np.sort(first)


def silhouette_lines(p: np.ndarray, ring: np.ndarray, step: float) -> list[tuple]:
    """Per scan line with >= 2 points: (angular width + one step, nearest range, median range
    of the facing points, line, lowest and highest azimuth, bearing of the points' mean)."""
    rho = np.hypot(p[:, 0], p[:, 1])
    az = np.arctan2(p[:, 1], p[:, 0])
    bearing = np.arctan2(p[:, 1].mean(), p[:, 0].mean())
    a = np.angle(np.exp(1j * (az - bearing)))
    out = []
    for line in np.unique(ring):
        m = ring == line
        if m.sum() < 2:
            continue
        lo, hi = a[m].min(), a[m].max()
        mid = 0.5 * (lo + hi)
        facing = np.abs(a[m] - mid) <= 0.25 * (hi - lo) + 1e-9
        front = np.median(rho[m][facing] * np.cos(a[m][facing] - mid))
        out.append((hi - lo + step, rho[m].min(), front, line, lo, hi, bearing))
    return out


def occluded(line: tuple, scan_p: np.ndarray, scan_ring: np.ndarray, step: float) -> bool:
    """True when a return of the line's ring within 1.5 steps beyond either edge lies more than
    0.15 m nearer than the line's front (the detector's edgeOccluded, on all raw returns)."""
    _, _, front, ring, lo, hi, bearing = line
    m = scan_ring == ring
    a = np.angle(np.exp(1j * (np.arctan2(scan_p[m, 1], scan_p[m, 0]) - bearing)))
    rho = np.hypot(scan_p[m, 0], scan_p[m, 1])
    beyond = ((a < lo) & (a >= lo - 1.5 * step)) | ((a > hi) & (a <= hi + 1.5 * step))
    return bool(np.any(beyond & (rho < front - 0.15)))


def radius(lines: list[tuple], mode: str, true_front: float = np.nan) -> float:
    r = []
    for w, dn, dmed, *_ in lines:
        s = np.sin(0.5 * w)
        if not (0 < s < 0.9):
            continue
        d = {"min": dn, "median": dmed, "true": true_front}[mode]
        r.append(d * s / (1 - s))
    return float(np.median(r)) if len(r) >= 2 else np.nan


def evaluate(
    sim: Path, n_scans: int, sensor: str, min_dbh: float, true_centre: bool = False
) -> dict:
    _, poses = read_tum(sim / "truth" / "trajectory.tum")
    trees = read_trees_csv(sim / "truth" / "trees.csv")
    world = np.c_[trees["x"], trees["y"], trees["z_ground"] + 1.3]
    profile = load_profile(sensor)
    step = np.deg2rad(profile.azimuth_resolution_deg)
    pick = set(np.linspace(0, len(poses) - 1, n_scans).astype(int).tolist())
    cfg = PerceptionConfig()
    half = cfg.diameter.band_max_half_m
    thr = profile.intensity_threshold
    voxel = cfg.filter.voxel_m
    rows = []  # (true range, truth dbh, gap, *variant dbh)
    for k, scan in enumerate(read_scans(next(sim.glob("sequence.*")))):
        if k not in pick:
            continue
        local = transform_points(np.linalg.inv(poses[k]), world)
        stems = detect(scan, sensor, cfg)
        for i in range(len(stems)):
            sil = stems.diameters[i].silhouette
            if not sil.valid:
                continue
            d = np.linalg.norm(local[:, :2] - stems.xy[i], axis=1)
            d[trees["dbh_m"] < min_dbh] = np.inf
            j = int(np.argmin(d))
            if d[j] > 0.5:
                continue
            r_true = 0.5 * trees["dbh_m"][j]
            centre = np.asarray(sil.centre)[:2]
            D_true = float(np.linalg.norm(local[j, :2]))
            mid = stems.base_z[i] + 1.3
            # raw returns around the detected centre, or (true_centre) the true one with a wider
            # margin: grazing edge returns carry several cm of range noise, and a detected centre
            # a few cm off would drop them from the selection and widen the gap
            select_at, pad = (local[j, :2], 0.15) if true_centre else (centre, 0.08)
            sec = (np.abs(scan.points[:, 2] - mid) <= half) & (
                np.linalg.norm(scan.points[:, :2] - select_at, axis=1) <= r_true + pad
            )
            if sec.sum() < 4:
                continue
            pts, ring = scan.points[sec], np.asarray(scan.ring)[sec].astype(int)
            inten = np.asarray(scan.intensity)[sec]
            sp = stems.points[i]
            sp = sp[np.abs(sp[:, 2] - mid) <= half]
            # the detector's stem points carry no ring: the nearest scan point's ring
            near_idx = np.argmin(np.linalg.norm(pts[None, :, :] - sp[:, None, :], axis=2), axis=1)
            lines_all = silhouette_lines(pts, ring, step)
            keep = inten <= thr if thr is not None else np.ones(len(pts), bool)  # not foliage
            vox = first_per_voxel(pts[keep], voxel)
            lines_vox = silhouette_lines(pts[keep][vox], ring[keep][vox], step)
            lines_thr = silhouette_lines(pts[keep], ring[keep], step) if keep.sum() >= 4 else []
            lines_stem = silhouette_lines(sp, ring[near_idx], step)
            true_w = 2 * np.arcsin(min(r_true / D_true, 0.99))
            gaps = np.array([(true_w - (ln[0] - step)) / (2 * step) for ln in lines_all])
            ring_all = np.asarray(scan.ring).astype(int)
            occ = np.array([occluded(ln, scan.points, ring_all, step) for ln in lines_all], bool)
            gap = gaps.mean() if len(gaps) else np.nan
            gap_clean = gaps[~occ].mean() if (~occ).any() else np.nan
            gap_occ = gaps[occ].mean() if occ.any() else np.nan
            rows.append(
                (
                    D_true,
                    2 * r_true,
                    gap,
                    gap_clean,
                    gap_occ,
                    occ.mean() if len(occ) else np.nan,
                    2 * sil.radius,
                    2 * radius(lines_stem, "min"),
                    2 * radius(lines_all, "min"),
                    2 * radius(lines_thr, "min") if lines_thr else np.nan,
                    2 * radius(lines_vox, "min") if lines_vox else np.nan,
                    2 * radius(lines_all, "median"),
                    2 * radius(lines_all, "true", D_true - r_true),
                )
            )
    return np.asarray(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sims", nargs="+", type=Path)
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--min-dbh", type=float, default=0.1)
    ap.add_argument(
        "--true-centre",
        action="store_true",
        help="select the raw returns around the true stem centre (r + 15 cm), not the detected",
    )
    args = ap.parse_args()
    for sim in args.sims:
        sensor = "hdl32" if "hdl32" in sim.name else "vlp16"
        rows = evaluate(sim, args.scans, sensor, args.min_dbh, args.true_centre)
        print(f"{sim.name}: {len(rows)} silhouettes; bias (MAE) cm per true-range bin")
        print(
            "  variant         "
            + "".join(
                f"{lo:>4.0f}-{hi:<4.0f} m      " for lo, hi in zip(BINS[:-1], BINS[1:], strict=True)
            )
        )
        for v, name in enumerate(VARIANTS):
            cells = []
            for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
                m = (rows[:, 0] >= lo) & (rows[:, 0] < hi)
                e = 100 * (rows[m, 6 + v] - rows[m, 1])
                e = e[np.isfinite(e)]
                cells.append(
                    f"{e.mean():+5.2f} ({np.abs(e).mean():4.2f}) n{len(e):<3d}"
                    if len(e)
                    else " " * 19
                )
            print(f"  {name:<15s} " + " ".join(cells))
        for col, name, unit in (
            (2, "gap per side", "steps"),
            (3, "  clean lines", "steps"),
            (4, "  occluded", "steps"),
            (5, "occluded share", "     "),
        ):
            cells = []
            for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
                m = (rows[:, 0] >= lo) & (rows[:, 0] < hi)
                ok = m & np.isfinite(rows[:, col])
                cells.append(
                    f"{rows[ok, col].mean():+5.2f} {unit}       " if ok.any() else " " * 19
                )
            print(f"  {name:<15s} " + " ".join(cells))


if __name__ == "__main__":
    main()
