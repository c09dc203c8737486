"""The C++ program `forestslam_odometry` (issue 18) beside the Python Odometry on the same scans.

For each scenario (default vlp16-loop, vlp16-rough; simulated sequences cached under
data/cache/sim/, shared with the other benches) the scans are written once as a folder of PCD
files named by their stamps (x y z intensity ring time; data/cache/pcd/<sequence>/), then run
  program  forestslam_odometry SCANS_DIR --sensor NAME --out trajectory.tum (no Python; its CPU
           time is the child process's, reading the PCD files included),
  python   forestslam.odometry.Odometry over the bag (the same C++ pipeline behind a wrapper;
           CPU time of this process, bag decoding excluded),
and prints ATE RMSE after SE(3) alignment and scans per CPU second; target: program >= 80.

    python bench/odometry_program_bench.py [--scenarios a,b] [--max-scans N] [--program PATH]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from sim_sequences import sensor_of, sequence  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / "data" / "cache"
PROGRAM = REPO / "build" / "py" / "cpp" / "apps" / "forestslam_odometry"


def export_pcd(seq: Path) -> Path:
    """The scans of seq/sequence.bag as <stamp>.pcd files (made once)."""
    from forestslam.io import read_scans
    from forestslam.io.pcd import write_pcd

    out = CACHE / "pcd" / seq.name
    done = out / ".complete"
    if done.is_file():
        return out
    out.mkdir(parents=True, exist_ok=True)
    for scan in read_scans(seq / "sequence.bag"):
        n = len(scan.points)
        cols = [("x", "f4"), ("y", "f4"), ("z", "f4")]
        extra = [("intensity", "f4", scan.intensity), ("ring", "u2", scan.ring)]
        extra.append(("time", "f8", scan.time))
        cols += [(name, t) for name, t, v in extra if v is not None]
        arr = np.zeros(n, dtype=cols)
        for i, axis in enumerate("xyz"):
            arr[axis] = scan.points[:, i]
        for name, _, v in extra:
            if v is not None:
                arr[name] = v
        write_pcd(out / f"{scan.stamp:.6f}.pcd", arr)
    done.touch()
    return out


def ate(seq: Path, stamps: np.ndarray, poses: np.ndarray) -> float:
    from forestslam.evaluation import trajectory_errors
    from forestslam.io import read_tum

    gs, gp = read_tum(seq / "truth" / "trajectory.tum")
    return float(trajectory_errors(stamps, poses, gs, gp)["ate_rmse_m"])


def run_program(program: Path, scans: Path, sensor: str, out: Path) -> tuple[float, int]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(
        [str(program), str(scans), "--sensor", sensor, "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    sys.stderr.write(proc.stderr)
    if proc.returncode != 0:
        raise SystemExit(f"{program} failed with exit {proc.returncode}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, len(out.read_text().splitlines())


def run_python(seq: Path, sensor: str) -> tuple[float, np.ndarray, np.ndarray]:
    from forestslam.io import read_scans
    from forestslam.odometry import Odometry

    odo = Odometry(sensor)
    stamps, poses, cpu = [], [], 0.0
    for scan in read_scans(seq / "sequence.bag"):
        c0 = time.process_time()
        step = odo.step(scan)
        cpu += time.process_time() - c0
        stamps.append(step.stamp)
        poses.append(step.T_world_sensor)
    return cpu, np.asarray(stamps), np.stack(poses)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default="vlp16-loop,vlp16-rough")
    ap.add_argument("--max-scans", type=int, default=None)
    ap.add_argument("--program", type=Path, default=PROGRAM)
    args = ap.parse_args()
    if not args.program.is_file():
        raise SystemExit(f"{args.program}: not built (dev.sh build)")
    from forestslam.io import read_tum

    ok = True
    print("scenario      scans  program ATE  python ATE  program scans/CPU s  python scans/CPU s")
    for name in [s.strip() for s in args.scenarios.split(",") if s.strip()]:
        seq = sequence(name, args.max_scans)
        sensor = sensor_of(seq)
        scans = export_pcd(seq)
        out = CACHE / "pcd" / f"{seq.name}.program.tum"
        cpu_prog, n = run_program(args.program, scans, sensor, out)
        ps, pp = read_tum(out)
        cpu_py, s_py, p_py = run_python(seq, sensor)
        rate_prog, rate_py = n / cpu_prog, len(s_py) / cpu_py
        ok &= rate_prog >= 80.0
        print(
            f"{name:<13}{n:>6}  {ate(seq, ps, pp):>10.3f}  {ate(seq, s_py, p_py):>10.3f}"
            f"  {rate_prog:>19.1f}  {rate_py:>18.1f}"
        )
    print("target program >= 80 scans per CPU second:", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
