"""KISS-ICP (PyPI `kiss-icp`) as the competitor of the odometry and SLAM benches.

One runner for both benches, so the baseline is configured and evaluated the same way:

- Configuration: KISS-ICP's own defaults, as its pipeline loads them (`load_config(None)`:
  max_range 100 m, min_range 0 m, deskew on, voxel_size = max_range / 100, 20 points per
  voxel, at most 500 ICP iterations, convergence 1e-4, adaptive threshold 2.0 / 0.1). The only
  changes: `max_range` is the sensor profile's maximum range when it is not 100 m (KISS-ICP's
  documented way to adapt it to a sensor; the voxel size follows from it by its own rule), and
  `max_num_threads=1` because the benches compare CPU time on one core.
- Input: the same scans as forestslam, with the per-point times (seconds from the scan stamp);
  KISS-ICP normalises them itself. Scans without per-point times go in without (KISS-ICP then
  skips deskewing, as its own pipeline does).
- Stamps: KISS-ICP 1.x deskews every point to the sweep's LAST instant (its Preprocessor applies
  Exp((s - 1) omega) with s the normalised time), so the pose it returns is the sensor pose at
  `stamp + max(time)`, one sweep (0.1 s at 10 Hz) after the stamp. The pose is stamped there.
  Stamping it at the sweep start, as this runner did before, lags it by one sweep against the
  truth (about 0.1 m at 1 m/s) and inflates its ATE; that figure is kept as a diagnostic
  (`ate_rmse_m_if_stamped_at_sweep_start`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def kiss_config(sensor: str):
    """KISS-ICP's default configuration for `sensor` (see the module docstring)."""
    from kiss_icp.config import load_config

    from forestslam.sensors import load_profile

    cfg = load_config(None)  # KISS-ICP's defaults, voxel size derived as its pipeline does
    max_range = float(load_profile(sensor).range_max_m)
    if max_range != cfg.data.max_range:
        cfg.data.max_range = max_range
        cfg.mapping.voxel_size = max_range / 100.0  # KISS-ICP's rule (config/parser.py)
    cfg.registration.max_num_threads = 1  # CPU time on one core
    return cfg


def describe(cfg) -> str:
    """One line naming every setting the run used."""
    d, m, r, a = cfg.data, cfg.mapping, cfg.registration, cfg.adaptive_threshold
    return (
        f"max_range {d.max_range:g} m, min_range {d.min_range:g} m, deskew {d.deskew}, voxel "
        f"{m.voxel_size:g} m, {m.max_points_per_voxel} points/voxel, <= "
        f"{r.max_num_iterations} iterations, convergence {r.convergence_criterion:g}, threads "
        f"{r.max_num_threads}, threshold {a.initial_threshold:g} / min motion {a.min_motion_th:g}"
    )


def run_kiss(seq: Path, sensor: str, tum_out: Path | None = None, log_every: int = 0) -> dict:
    """KISS-ICP over `seq`/sequence.bag, evaluated against `seq`/truth/trajectory.tum.

    Returns the figures of `forestslam.evaluation.trajectory_errors` plus ms_per_scan (wall),
    cpu_ms_per_scan (CPU of this process), scans, config and the sweep-start diagnostic.
    `tum_out` keeps the trajectory (TUM); `log_every` > 0 prints progress every that many scans.
    """
    from kiss_icp.kiss_icp import KissICP

    from forestslam.evaluation import trajectory_errors
    from forestslam.io import read_scans, read_tum, write_tum

    cfg = kiss_config(sensor)
    kiss = KissICP(cfg)
    stamps, starts, poses, wall, cpu = [], [], [], [], []
    no_times = np.zeros(0, dtype=np.float64)
    for scan in read_scans(seq / "sequence.bag"):
        has_times = scan.time is not None and len(scan.time) > 0
        times = np.ascontiguousarray(scan.time, dtype=np.float64) if has_times else no_times
        w0, c0 = time.perf_counter(), time.process_time()
        kiss.register_frame(scan.points, times)
        wall.append((time.perf_counter() - w0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
        end = float(np.max(times)) if has_times and cfg.data.deskew else 0.0
        stamps.append(scan.stamp + end)
        starts.append(scan.stamp)
        poses.append(np.asarray(kiss.last_pose, dtype=np.float64).copy())
        if log_every and len(stamps) % log_every == 0:
            print(
                f"    KISS-ICP {len(stamps)} scans, {np.mean(cpu[-log_every:]):.0f} ms CPU per "
                f"scan over the last {log_every} ({time.strftime('%H:%M:%S')})",
                flush=True,
            )
    gs, gp = read_tum(seq / "truth" / "trajectory.tum")
    m = trajectory_errors(np.asarray(stamps), np.stack(poses), gs, gp)
    m.pop("alignment", None)
    lagged = trajectory_errors(np.asarray(starts), np.stack(poses), gs, gp)
    m["ate_rmse_m_if_stamped_at_sweep_start"] = lagged["ate_rmse_m"]
    m["ms_per_scan"] = float(np.mean(wall))
    m["ms_per_scan_median"] = float(np.median(wall))
    m["cpu_ms_per_scan"] = float(np.mean(cpu))
    m["cpu_ms_per_scan_median"] = float(np.median(cpu))
    m["scans"] = len(stamps)
    m["config"] = describe(cfg)
    if tum_out is not None:
        tum_out.parent.mkdir(parents=True, exist_ok=True)
        write_tum(tum_out, np.asarray(stamps), np.stack(poses))
    return m
