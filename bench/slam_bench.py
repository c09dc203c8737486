"""SLAM benchmark (issue 6): forestslam SLAM beside KISS-ICP on the simulator's loops.

For each scenario (default vlp16-loop, vlp16-rough, hdl32-loop; cached under data/cache/sim/):
runs `forestslam run --mode slam` and KISS-ICP (PyPI) on the same scans, evaluates both
against the truth, and prints ATE, RPE, drift, tree recall / precision, DBH errors and speed,
with the targets: SLAM ATE <= 0.25 m and <= 0.5 x KISS-ICP; recall, precision >= 0.90; DBH MAE
<= 3 cm; >= 10 scans/s on one core (VLP-16). Then a memory run: the first VLP-16 sequence
replayed (stamps shifted) for --rss-scans scans, RSS read from /proc/self/status after 500
scans and at the end (target growth <= 200 MB).

    python bench/slam_bench.py [--scenarios a,b] [--max-scans N] [--rss-scans 3000] [--no-kiss]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, for the competitor too
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from sim_sequences import sensor_of, sequence  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / "data" / "cache"
SCENARIOS = ("vlp16-loop", "vlp16-rough", "hdl32-loop")


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def run_kiss(seq: Path, sensor: str) -> dict:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    from forestslam.evaluation import trajectory_errors
    from forestslam.io import read_scans, read_tum
    from forestslam.sensors import load_profile

    profile = load_profile(sensor)
    cfg = KISSConfig()
    cfg.data.max_range = float(profile.range_max_m)
    cfg.data.min_range = float(profile.range_min_m)
    cfg.mapping.voxel_size = cfg.data.max_range / 100.0
    cfg.registration.max_num_threads = 1
    kiss = KissICP(cfg)
    stamps, poses = [], []
    t0 = time.perf_counter()
    for scan in read_scans(seq / "sequence.bag"):
        times = scan.time if scan.time is not None else np.zeros(len(scan))
        kiss.register_frame(scan.points, times.astype(np.float64))
        stamps.append(scan.stamp)
        poses.append(np.asarray(kiss.last_pose).copy())
    wall = time.perf_counter() - t0
    gs, gp = read_tum(seq / "truth" / "trajectory.tum")
    m = trajectory_errors(np.asarray(stamps), np.stack(poses), gs, gp)
    m["scans_per_s"] = len(stamps) / wall
    return m


def run_ours(seq: Path, sensor: str, out: Path) -> tuple[dict, object]:
    from forestslam.evaluation.report import evaluate_run
    from forestslam.runner import run

    summary = run(seq / "sequence.bag", sensor, out, mode="slam", progress=False)
    metrics = evaluate_run(out, seq / "truth")
    return metrics, summary


def rss_run(seq: Path, sensor: str, n_scans: int) -> dict:
    """Replay the sequence until n_scans scans went through the pipeline; RSS at 500 and end."""
    from forestslam.config import load_config
    from forestslam.io import read_scans
    from forestslam.runner import Pipeline
    from forestslam.sensors import load_profile

    out = CACHE / "bench-slam" / "rss"
    pipe = Pipeline(load_profile(sensor), load_config(None), "slam", out)
    offset, n, rss500 = 0.0, 0, None
    t0 = time.perf_counter()
    while n < n_scans:
        first = last = None
        for scan in read_scans(seq / "sequence.bag"):
            first = scan.stamp if first is None else first
            last = scan.stamp
            scan.stamp += offset  # the replay continues in time
            pipe.process(scan)
            n += 1
            if n == 500:
                rss500 = rss_mb()
            if n >= n_scans:
                break
        offset += last - first + 0.1
    return {
        "scans": n,
        "rss_500_mb": rss500,
        "rss_end_mb": rss_mb(),
        "growth_mb": rss_mb() - (rss500 or 0.0),
        "trees": pipe.slam.n_landmarks,
        "scans_per_s": n / (time.perf_counter() - t0),
    }


def fmt(v, digits=3):
    return "n/a" if v is None else f"{v:.{digits}f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--max-scans", type=int, default=None, help="shorten the sequences")
    ap.add_argument("--rss-scans", type=int, default=3000, help="0 skips the memory run")
    ap.add_argument("--no-kiss", action="store_true")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    results = {}
    for name in args.scenarios.split(","):
        print(f"== {name}", flush=True)
        seq = sequence(name, args.max_scans)
        sensor = sensor_of(seq)
        m, s = run_ours(seq, sensor, CACHE / "bench-slam" / name)
        k = None if args.no_kiss else run_kiss(seq, sensor)
        t, o, tr = m["trajectory"], m.get("odometry", {}), m.get("trees", {})
        ratio = t["ate_rmse_m"] / k["ate_rmse_m"] if k else None
        rows = [
            ("", "SLAM", "odometry", "KISS-ICP"),
            (
                "ATE RMSE [m]",
                fmt(t["ate_rmse_m"]),
                fmt(o.get("ate_rmse_m")),
                fmt(k["ate_rmse_m"]) if k else "-",
            ),
            (
                "RPE 10 m [%]",
                fmt(t["rpe_percent_10m"], 2),
                fmt(o.get("rpe_percent_10m"), 2),
                fmt(k["rpe_percent_10m"], 2) if k else "-",
            ),
            (
                "final drift [m]",
                fmt(t["final_drift_m"]),
                fmt(o.get("final_drift_m")),
                fmt(k["final_drift_m"]) if k else "-",
            ),
            ("scans/s", fmt(s.scans_per_s, 1), "", fmt(k["scans_per_s"], 1) if k else "-"),
        ]
        for r in rows:
            print(f"  {r[0]:<18}{r[1]:>10}{r[2]:>10}{r[3]:>10}")
        print(
            f"  trees: recall {fmt(tr.get('recall'))} precision {fmt(tr.get('precision'))} "
            f"(truth {tr.get('n_truth')}, est {tr.get('n_est')}, matched {tr.get('n_matched')}), "
            f"pos err {fmt(tr.get('mean_position_error_m'))} m, DBH MAE "
            f"{fmt((tr.get('dbh_mae_m') or float('nan')) * 100, 2)} cm, RMSE "
            f"{fmt((tr.get('dbh_rmse_m') or float('nan')) * 100, 2)} cm, bias "
            f"{fmt((tr.get('dbh_bias_m') or float('nan')) * 100, 2)} cm"
        )
        checks = {
            "ATE <= 0.25 m": t["ate_rmse_m"] <= 0.25,
            "ATE <= 0.5 x KISS": ratio is not None and ratio <= 0.5,
            "recall >= 0.90": (tr.get("recall") or 0) >= 0.9,
            "precision >= 0.90": (tr.get("precision") or 0) >= 0.9,
            "DBH MAE <= 3 cm": (tr.get("dbh_mae_m") or 1) <= 0.03,
        }
        if sensor == "vlp16":
            checks[">= 10 scans/s"] = s.scans_per_s >= 10
        print(
            f"  ATE ratio SLAM/KISS: {fmt(ratio, 2)}; loop closures {s.loop_closures}, "
            f"{s.scans} scans, {s.keyframes} keyframes, {s.degraded_scans} degraded"
        )
        print(
            "  " + ", ".join(f"{k_}: {'PASS' if v else 'FAIL'}" for k_, v in checks.items()),
            flush=True,
        )
        results[name] = {"slam": m, "kiss": k, "summary": s.to_dict(), "checks": checks}
    if args.rss_scans:
        first = args.scenarios.split(",")[0]
        seq = sequence(first, args.max_scans)
        r = rss_run(seq, sensor_of(seq), args.rss_scans)
        ok = r["growth_mb"] <= 200
        print(
            f"== memory: {r['scans']} scans ({first} replayed), RSS after 500 "
            f"{r['rss_500_mb']:.0f} MB, at end {r['rss_end_mb']:.0f} MB, growth "
            f"{r['growth_mb']:.0f} MB ({'PASS' if ok else 'FAIL'} <= 200 MB), "
            f"{r['scans_per_s']:.1f} scans/s"
        )
        results["memory"] = r

    def plain(o):
        if isinstance(o, dict):
            return {k: plain(v) for k, v in o.items()}
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        return o

    out = CACHE / "bench-slam" / "results.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(plain(results), indent=1, default=str))
    print(f"results -> {out}")


if __name__ == "__main__":
    sys.exit(main())
