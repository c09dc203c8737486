"""`forestslam tls-register`: read inputs, register, write the plot products atomically."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import planar_pose
from forestslam.io import Scan, read_cloud, read_scans, write_cloud, write_trees_csv, write_tum
from forestslam.io.atomic import atomic_write_text
from forestslam.sensors import load_profile
from forestslam.tls.config import TlsConfig
from forestslam.tls.pipeline import TlsRun, register_mls_to_tls, unmerged_csv, unmerged_summary
from forestslam.tls.trees import (
    circumference_coverage,
    fuse_with_reference,
    observations,
    plot_trees,
)

log = logging.getLogger(__name__)

BAG_SUFFIXES = {".bag", ".mcap", ".db3"}


def load_reference(path: str | Path) -> np.ndarray:
    """Reference cloud (R,3): any cloud file read_cloud accepts, or a bag holding one scan."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: reference not found")
    if path.suffix.lower() in BAG_SUFFIXES or path.is_dir():
        scans = list(read_scans(path))
        if len(scans) != 1:
            raise InputError(
                f"{path}: a reference bag must hold exactly one scan, it holds {len(scans)}"
            )
        return scans[0].points
    return read_cloud(path).points


def with_rings(scans, sensor: str):
    """Scans with a ring per point: kept when present, else from the profile's beam angles
    (spinning sensors); for other profiles rings stay None (layers are used instead)."""
    profile = load_profile(sensor)
    angles = np.asarray(profile.vertical_angles_rad) if profile.kind == "spinning" else None
    for scan in scans:
        if scan.ring is None and angles is not None and len(angles) > 1:
            p = np.asarray(scan.points, dtype=np.float64)
            el = np.arctan2(p[:, 2], np.linalg.norm(p[:, :2], axis=1))
            order = np.argsort(angles)
            pos = np.clip(np.searchsorted(angles[order], el), 1, len(angles) - 1)
            left, right = angles[order][pos - 1], angles[order][pos]
            nearest = np.where(el - left < right - el, pos - 1, pos)
            ring = order[nearest].astype(np.uint16)
            scan = Scan(scan.stamp, scan.points, scan.intensity, ring, scan.time)
        yield scan


def parse_initial_pose(text: str | None) -> np.ndarray | None:
    """'x,y,yaw_deg' or 'x,y,z,yaw_deg' -> (4,4) T_tls_sensor."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise InputError(f"--initial-pose {text!r}: expected x,y,yaw_deg or x,y,z,yaw_deg") from exc
    if len(values) not in (3, 4) or not np.all(np.isfinite(values)):
        raise InputError(f"--initial-pose {text!r}: expected x,y,yaw_deg or x,y,z,yaw_deg")
    z = values[2] if len(values) == 4 else 0.0
    return planar_pose(values[0], values[1], np.radians(values[-1]), z)


def write_products(run: TlsRun, out_dir: Path, config: TlsConfig, title: str = "") -> dict:
    """trajectory.tum, plot.laz, trees.csv, coverage.json, unmerged.csv, plot.png; returns
    the summary."""
    from forestslam.tls.plotting import plot_tls_run

    out_dir.mkdir(parents=True, exist_ok=True)
    write_tum(out_dir / "trajectory.tum", run.stamps, run.poses)
    write_cloud(out_dir / "plot.laz", run.map_points)
    views = (run.views, (config.map.frame_min_range_m, config.map.frame_max_range_m))
    trees = plot_trees(run.map_points, config.trees, config.features, *views)
    trees = fuse_with_reference(trees, run.reference, config.trees, config.features, *views)
    cov_tls = circumference_coverage(run.reference, trees, config.trees)
    cov_merged = circumference_coverage(run.map_points, trees, config.trees)
    obs = observations(trees, run.frame_centres, cov_tls > 0)
    write_trees_csv(
        out_dir / "trees.csv",
        {
            "id": np.arange(len(trees)),
            "x": trees.xyz[:, 0],
            "y": trees.xyz[:, 1],
            "z": trees.xyz[:, 2],
            "dbh_m": trees.dbh_m,
            "dbh_std_m": trees.dbh_std_m,
            "observations": obs,
        },
    )
    coverage = {
        "band_m": list(config.trees.band_m),
        "sectors": config.trees.coverage_sectors,
        "mean_tls": float(cov_tls.mean()) if len(trees) else None,
        "mean_merged": float(cov_merged.mean()) if len(trees) else None,
        "stems": [
            {"id": int(k), "tls": float(cov_tls[k]), "merged": float(cov_merged[k])}
            for k in range(len(trees))
        ],
    }
    atomic_write_text(out_dir / "coverage.json", json.dumps(coverage, indent=1) + "\n")
    atomic_write_text(out_dir / "unmerged.csv", unmerged_csv(run))
    plot_tls_run(
        out_dir / "plot.png",
        run.map_points,
        trees.xyz,
        trees.dbh_m,
        cov_tls,
        cov_merged,
        run.poses,
        trees.base_z,
        title=title or "MLS + TLS plot",
    )
    frames = run.frames
    return {
        "frames": len(frames),
        "accepted": int(sum(f.accepted for f in frames)),
        "stems": len(trees),
        "map_points": int(len(run.map_points)),
        "coverage_tls": coverage["mean_tls"],
        "coverage_merged": coverage["mean_merged"],
        "ms_features_lm_mean": float(np.mean([f.ms_features + f.ms_lm for f in frames])),
        "ms_all_mean": float(
            np.mean([f.ms_features + f.ms_lm + f.ms_ndt + f.ms_target for f in frames])
        ),
        "fallback_frames": int(sum(f.fallback for f in frames)),
        "initial_pose": run.initial_method,
        "without_pose": len(run.unplaced),
        "unmerged": unmerged_summary(run),
    }


def run_tls_register(
    input_path: str | Path,
    reference_path: str | Path,
    sensor: str,
    out_dir: str | Path,
    config: TlsConfig | None = None,
    initial_pose: np.ndarray | None = None,
    topic: str | None = None,
    on_frame=None,
    start: int = 0,
    max_scans: int | None = None,
    progress: bool = False,
    overwrite: bool = False,
) -> dict:
    """Register the MLS scans of the window onto the reference; writes the plot products and
    run.yaml into `out_dir` (owned as `forestslam.job` describes). Returns the summary."""
    from forestslam.config_utils import to_dict, validate
    from forestslam.job import Job, Progress, ScanWindow

    window = ScanWindow(start, max_scans)
    config = validate(config or TlsConfig(), "tls")
    reference = load_reference(reference_path)
    stream, scans, count = window.open(input_path, topic)  # `start` skipped undecoded
    meta = {
        "input": str(input_path),
        "reference": str(reference_path),
        "topic": topic,
        "sensor": sensor,
        **window.meta(),
        "initial_pose": None if initial_pose is None else np.asarray(initial_pose).tolist(),
        "config": {"tls": to_dict(config)},
    }
    inputs = [input_path, reference_path]
    with Job("tls-register", out_dir, meta, inputs=inputs, overwrite=overwrite) as job:
        bar = Progress(count, "frame", "tls-register", enabled=progress)

        def frame_done(record) -> None:
            bar.update(1, accepted=record.accepted, stems_rms=f"{record.virtual_rms_m:.3f}")
            if on_frame is not None:
                on_frame(record)

        try:
            run = register_mls_to_tls(
                with_rings(scans, sensor), reference, config, initial_pose, on_frame=frame_done
            )
        finally:
            bar.close()
        job.summary = write_products(run, job.out, config, title=Path(input_path).name)
        job.summary["read_stats"] = stream.stats.to_dict() if hasattr(stream, "stats") else {}
    return job.summary
