"""`forestslam tls-register`: read inputs, register, write the plot products atomically."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import parse_yaw, planar_pose
from forestslam.io import Scan, read_cloud, read_scans, write_cloud, write_trees_csv, write_tum
from forestslam.io.atomic import atomic_write_text
from forestslam.sensors import load_profile
from forestslam.tls.config import TlsConfig
from forestslam.tls.frame import LocalFrame
from forestslam.tls.pipeline import (
    TlsRun,
    merged_range_m,
    register_mls_to_tls,
    unmerged_csv,
    unmerged_summary,
)
from forestslam.tls.trees import (
    circumference_coverage,
    fuse_with_reference,
    observations,
    plot_trees,
    reference_scanners,
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
    if path.suffix.lower() in (".las", ".laz"):
        return _las_xyz(path)
    return read_cloud(path).points


def reference_viewpoint(path: str | Path) -> np.ndarray | None:
    """The scanner position (3,) the reference file gives in its own frame, when its format
    has one (a .pcd VIEWPOINT); None otherwise (LAS/LAZ, PLY and bags carry none)."""
    if Path(path).suffix.lower() != ".pcd":
        return None
    from forestslam.io.pcd import read_pcd_viewpoint

    return read_pcd_viewpoint(path)


def _las_xyz(path: Path) -> np.ndarray:
    """The points (R,3) of a LAS/LAZ file as read_cloud keeps them (finite, not at the origin),
    without its structured copy of every field (1.4 -> 1.2 s CPU for a 4.4 M point plot, of
    which 1.0 s is the LAZ decompression)."""
    import laspy

    try:
        las = laspy.read(path)
    except Exception as exc:  # noqa: BLE001 - laspy raises many types for bad files
        raise InputError(f"{path}: cannot read LAS/LAZ ({exc})") from None
    # Scaled from the integer records (as laspy scales them; its lazy x/y/z views cost 0.3 s).
    raw, scales, offsets = las.points.array, las.header.scales, las.header.offsets
    pts = np.empty((len(raw), 3))
    for k, name in enumerate("XYZ"):
        pts[:, k] = raw[name] * scales[k] + offsets[k]
    keep = np.isfinite(pts).all(axis=1) & np.any(pts != 0, axis=1)
    return pts if keep.all() else pts[keep]


def with_rings(scans, sensor):
    """Scans with a ring per point: kept when present, else from the profile's beam angles
    (spinning sensors); for other profiles rings stay None (layers are used instead). `sensor`:
    a profile or its name."""
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
    """'x,y,yaw_deg' or 'x,y,z,yaw_deg' -> (4,4) T_tls_sensor (the yaw as geometry.parse_yaw
    reads it: degrees, or with a unit)."""
    if text is None:
        return None
    *head, last = text.split(",")
    try:
        values = [float(v) for v in head]
        yaw = parse_yaw(last, "--initial-pose")
    except ValueError as exc:
        raise InputError(f"--initial-pose {text!r}: expected x,y,yaw_deg or x,y,z,yaw_deg") from exc
    if len(values) not in (2, 3) or not np.all(np.isfinite(values)):
        raise InputError(f"--initial-pose {text!r}: expected x,y,yaw_deg or x,y,z,yaw_deg")
    z = values[2] if len(values) == 3 else 0.0
    return planar_pose(values[0], values[1], yaw, z)


def write_products(
    run: TlsRun,
    out_dir: Path,
    config: TlsConfig,
    title: str = "",
    viewpoint: np.ndarray | None = None,
    frame: LocalFrame | None = None,
) -> dict:
    """trajectory.tum, plot.laz, trees.csv, coverage.json, unmerged.csv, plot.png; returns
    the summary. viewpoint: the scanner position the reference file gives (reference_viewpoint;
    see trees.reference_scanners for where the face test takes the reference's scanners).
    frame: the local frame `run` is in (tls.frame); the products are in the reference's."""
    from forestslam.tls.plotting import plot_tls_run

    frame = frame or LocalFrame.identity()
    out_dir.mkdir(parents=True, exist_ok=True)
    poses = frame.poses_out(run.poses)
    map_points = frame.points_out(run.map_points)
    write_tum(out_dir / "trajectory.tum", run.stamps, poses)
    write_cloud(out_dir / "plot.laz", map_points)
    trees, scanners = _plot_trees(run, config, viewpoint, frame)
    cov_tls = circumference_coverage(run.reference, trees, config.trees)
    cov_merged = circumference_coverage(run.map_points, trees, config.trees)
    obs = observations(trees, run.frame_centres, cov_tls > 0)
    tree_xyz = frame.points_out(trees.xyz)
    write_trees_csv(
        out_dir / "trees.csv",
        {
            "id": np.arange(len(trees)),
            "x": tree_xyz[:, 0],
            "y": tree_xyz[:, 1],
            "z": tree_xyz[:, 2],
            "dbh_m": trees.dbh_m,
            "dbh_std_m": trees.dbh_std_m,
            "position_measured": trees.position_measured.astype(np.int64),
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
        map_points,
        tree_xyz,
        trees.dbh_m,
        cov_tls,
        cov_merged,
        poses,
        trees.base_z + frame.offset[2],
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
        "reference_scanners": {"xy": frame.xy_out(scanners.xy).tolist(), "source": scanners.source},
        "local_frame_offset": frame.offset.tolist(),
    }


def _plot_trees(run: TlsRun, config: TlsConfig, viewpoint: np.ndarray | None, frame: LocalFrame):
    """The merged map's stems fused with the reference's (trees.fuse_with_reference), and the
    reference's scanner positions the face test used (trees.reference_scanners, logged), in
    the run's local frame."""
    views = (run.views, (config.map.frame_min_range_m, merged_range_m(config)))
    trees = plot_trees(
        run.map_points, config.trees, config.features, *views, run.reference, run.map_counts
    )
    origin = -frame.offset[:2]
    scanners = reference_scanners(run.reference, config.trees, viewpoint, trees, origin)
    log.info(
        "face test: reference scanners %s (%s)",
        np.round(frame.xy_out(scanners.xy), 3).tolist() or "none",
        scanners.source,
    )
    trees = fuse_with_reference(trees, run.reference, config.trees, config.features, scanners)
    return trees, scanners


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
    profile = load_profile(sensor)
    reference = load_reference(reference_path)
    frame = LocalFrame.for_reference(reference)  # shifted in here, products shifted back
    reference = frame.points_in(reference)
    viewpoint = reference_viewpoint(reference_path)
    # `start` skipped undecoded; raw Velodyne packets decoded as the profile says
    stream, scans, count = window.open(input_path, topic, profile.packet_config())
    meta = {
        "input": str(input_path),
        "reference": str(reference_path),
        "topic": topic,
        "sensor": profile.name,
        **window.meta(),
        "initial_pose": None if initial_pose is None else np.asarray(initial_pose).tolist(),
        "config": {"tls": to_dict(config)},
    }
    inputs = [input_path, reference_path]
    with Job("tls-register", out_dir, meta, inputs=inputs, overwrite=overwrite) as job:
        bar = Progress(count, "frame", "tls-register", enabled=progress)
        frame_done = _frame_done(job, config, bar, on_frame, frame)
        T_init = frame.pose_in(initial_pose)
        try:
            run = register_mls_to_tls(
                with_rings(scans, profile), reference, config, T_init, on_frame=frame_done
            )
        finally:
            bar.close()
        title = Path(input_path).name
        job.summary = write_products(run, job.out, config, title, viewpoint, frame)
        job.summary["read_stats"] = stream.stats.to_dict() if hasattr(stream, "stats") else {}
    return job.summary


def _frame_done(job, config: TlsConfig, bar, on_frame, frame: LocalFrame):
    """The per-frame callback: progress, the caller's `on_frame`, and a checkpoint every
    config.checkpoint_every_frames frames (trajectory.tum of the frames registered so far and
    run.yaml with their counts; the final outputs replace both)."""
    from forestslam.job import Checkpoints

    checkpoints = Checkpoints(config.checkpoint_every_frames)
    records = []

    def write_trajectory() -> None:
        done = sorted(records, key=lambda r: r.stamp)
        poses = frame.poses_out(np.array([r.T_tls_sensor for r in done]))
        write_tum(job.out / "trajectory.tum", np.array([r.stamp for r in done]), poses)

    def frame_done(record) -> None:
        records.append(record)
        bar.update(1, accepted=record.accepted, stems_rms=f"{record.virtual_rms_m:.3f}")
        if on_frame is not None:
            on_frame(record)
        if checkpoints.due(len(records)):
            job.summary = {"frames": len(records), "accepted": sum(r.accepted for r in records)}
            job.checkpoint(write_trajectory)

    return frame_done
