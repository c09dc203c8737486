"""The main job: scans -> odometry -> landmark SLAM -> tree map (-> ground map), written as it goes.

Modes: `odometry` (odometry.tum, timing.json), `slam` (+ trajectory.tum, trees.csv/.geojson,
map.png), `map3d` (+ voxelized ground map rebuilt from the optimised keyframes: ground.ply,
dtm.npz/.csv/.png).
Output frame: the first processed scan's sensor frame.

Reliability: trajectory.tum, odometry.tum, trees.csv and trees.geojson are rewritten atomically
every `mapping.checkpoint_every_scans` scans, so a process killed mid-run leaves valid files up
to its last checkpoint; run.yaml says `status: running` until the run ends. Corrupt messages are
skipped by the reader and counted (`read_stats` in run.yaml); a scan the odometry cannot use is
skipped and counted; stretches without trees are bridged by odometry.
"""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from forestslam.errors import ForestSlamError, InputError
from forestslam.geometry import inverse, transform_points
from forestslam.georef import Georeference
from forestslam.output_frame import OutputFrame

log = logging.getLogger(__name__)

MODES = ("slam", "map3d", "odometry")


@dataclass
class RunSummary:
    out_dir: Path
    mode: str
    scans: int = 0
    failed_scans: int = 0
    degraded_scans: int = 0
    keyframes: int = 0
    trees: int = 0
    loop_closures: int = 0  # verified by place recognition only
    reassociation_corrections: int = 0  # drift corrections found by re-association (not closures)
    failed_updates: int = 0  # back-end updates that failed and were rolled back
    icp_accepted: int = 0
    icp_rejected: int = 0
    wall_s: float = 0.0
    scans_per_s: float = 0.0
    cpu_s: float = 0.0  # CPU time of this process (all threads) over the run
    cpu_scans_per_s: float = 0.0  # scans per CPU second: the rate one dedicated core gives
    status: str = "running"
    read_stats: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "mode": self.mode,
            "status": self.status,
            "scans": self.scans,
            "failed_scans": self.failed_scans,
            "degraded_scans": self.degraded_scans,
            "keyframes": self.keyframes,
            "trees": self.trees,
            "loop_closures": self.loop_closures,
            "reassociation_corrections": self.reassociation_corrections,
            "failed_updates": self.failed_updates,
            "icp_accepted": self.icp_accepted,
            "icp_rejected": self.icp_rejected,
            "wall_s": round(self.wall_s, 3),
            "scans_per_s": round(self.scans_per_s, 2),
            "cpu_s": round(self.cpu_s, 3),
            "cpu_scans_per_s": round(self.cpu_scans_per_s, 2),
            "read_stats": self.read_stats,
        }


def _versions() -> dict:
    import gtsam
    import scipy

    import forestslam

    return {
        "forestslam": forestslam.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "gtsam": getattr(gtsam, "__version__", "unknown"),
        "platform": platform.platform(),
    }


class _Timer:
    """Per-stage milliseconds per scan."""

    def __init__(self) -> None:
        self.stages: dict[str, list[float]] = {}
        self.n = 0

    def add(self, scan: int, stage: str, ms: float) -> None:
        col = self.stages.setdefault(stage, [])
        if len(col) < scan:
            col.extend([0.0] * (scan - len(col)))
        col.append(float(ms))

    def summary(self) -> dict:
        out = {}
        for name, v in self.stages.items():
            a = np.asarray(v)
            out[name] = {
                "mean_ms": float(a.mean()),
                "median_ms": float(np.median(a)),
                "p95_ms": float(np.percentile(a, 95)),
                "max_ms": float(a.max()),
            }
        return out

    def to_dict(self, per_scan: bool) -> dict:
        d: dict[str, Any] = {"scans": self.n, "stages": self.summary()}
        if per_scan:
            d["per_scan_ms"] = {k: [round(x, 3) for x in v] for k, v in self.stages.items()}
        return d


@dataclass
class RunOptions:
    """What a run adds to the plain job: a prior map to start in (multisession.PriorMap) and the
    first scan's pose there (x, y, yaw in its local frame), injected drift (tests, benches), the
    georeference of the outputs, and a live viewer (forestslam.viewer.RerunView)."""

    prior_map: Any = None
    initial_pose: np.ndarray | None = None
    drift: Any = None
    georef: Any = None
    viewer: Any = None


class Pipeline:
    """Holds the state of one run; `process(scan)` per scan, `write(final)` for outputs."""

    def __init__(
        self, sensor, config, mode: str, out_dir: Path, options: RunOptions | None = None
    ) -> None:
        from forestslam.mapping import GroundMap, TreeMap
        from forestslam.slam import LandmarkSlam

        try:
            from forestslam.odometry import Odometry
        except ImportError as exc:
            raise ForestSlamError(f"odometry is not available in this build ({exc})") from exc
        if mode not in MODES:
            raise InputError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")
        self.cfg = config
        self.mode = mode
        self.out_dir = out_dir
        self.odometry = Odometry(  # the run does not use the per-stem fit quality dicts
            sensor,
            getattr(config, "odometry", None),
            getattr(config, "perception", None),
            stem_fits=False,
        )
        self.slam = LandmarkSlam(config.slam) if mode != "odometry" else None
        step = float(np.radians(sensor.azimuth_resolution_deg))  # the DBH resolution gate
        self.trees = TreeMap(config.mapping, azimuth_step_rad=step) if mode != "odometry" else None
        self.ground = (
            GroundMap(config.mapping.ground_keyframe_voxel_m, config.mapping.ground_voxel_m)
            if mode == "map3d"
            else None
        )
        self.refiner = None
        if mode == "map3d" and config.mapping.refine_with_icp:
            from forestslam.mapping.refine import ScanToMapRefiner

            self.refiner = ScanToMapRefiner(config.mapping)
        opts = options or RunOptions()
        self.prior = None  # multisession.PriorTracker when the run starts in a prior map
        if opts.prior_map is not None:
            if mode == "odometry":
                raise InputError("--prior-map needs --mode slam or map3d (trees to place)")
            from forestslam.multisession.prior import PriorTracker

            self.prior = PriorTracker(opts.prior_map, config.prior_map, config.localization)
        self.initial_pose = opts.initial_pose  # (3,) x, y, yaw of the first scan in the map
        self.loops = None  # place recognition: loop closure when re-association cannot
        if self.slam is not None and config.place_recognition.enabled:
            from forestslam.multisession.loops import PlaceRecognition

            self.loops = PlaceRecognition(config.place_recognition, config.localization)
        self.drift = opts.drift  # a DriftInjector corrupting the odometry (tests and benches)
        self.frame = OutputFrame(opts.georef or Georeference(), self.prior)
        self.viewer = opts.viewer
        self.cloud = None  # the registered cloud for map.laz
        if self.slam is not None and config.mapping.map_laz:
            from forestslam.mapping.cloud_map import CloudMap

            self.cloud = CloudMap(config.mapping.map_voxel_m, config.mapping.map_voxel_m)
        self.timer = _Timer()
        self.stamps: list[float] = []
        self.odom: list[np.ndarray] = []
        self._T0_inv: np.ndarray | None = None
        self.n = 0
        self.failed = 0
        self.degraded = 0

    def process(self, scan) -> None:
        t_start = time.perf_counter()
        try:
            step = self.odometry.step(scan)
        except ForestSlamError as exc:
            self.failed += 1
            log.warning("scan at %.3f s skipped: %s", scan.stamp, exc)
            return
        t_odom = time.perf_counter()
        i = self.n
        for name, ms in (step.timing or {}).items():
            self.timer.add(i, f"odometry.{name}", ms)
        self.timer.add(i, "odometry", (t_odom - t_start) * 1e3)
        T = np.asarray(step.T_world_sensor, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            self.failed += 1
            log.warning("scan at %.3f s skipped: non-finite odometry pose", scan.stamp)
            return
        if self._T0_inv is None:
            self._T0_inv = inverse(T)
        T = self._T0_inv @ T  # output frame: the first scan's sensor frame
        if self.drift is not None:
            T = self.drift.apply(T)
        self.stamps.append(float(step.stamp))
        self.odom.append(T)
        self.degraded += bool(step.degraded)
        if self.viewer is not None:
            self.viewer.scan(i, step.stamp, T, scan.points)
        if self.slam is not None:
            try:
                self._map(i, step, T, scan)
            except ForestSlamError as exc:  # the scan keeps its odometry pose
                self.failed += 1
                log.error("scan at %.3f s: mapping failed: %s", scan.stamp, exc)
            self.timer.add(i, "slam_mapping", (time.perf_counter() - t_odom) * 1e3)
        self.timer.add(i, "total", (time.perf_counter() - t_start) * 1e3)
        self.n += 1
        self.timer.n = self.n

    def _map(self, i: int, step, T: np.ndarray, scan) -> None:
        from forestslam.slam import level_points

        stems = step.stems
        k = 0 if stems is None else len(stems.xy)
        if k:
            centre = np.column_stack([stems.xy, stems.z])
            level = level_points(T, centre)
            z_odom = level[:, 2] + T[2, 3]  # centre heights in the odometry frame
            level = level[:, :2]
            dbh = np.asarray(stems.dbh, dtype=np.float64)
        else:
            centre, level, dbh, z_odom = np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), None
        source = None
        if self.refiner is not None and stems is not None:
            source = self.refiner.source_points(stems)
            self.slam.refine_hook = self._refine_hook(T, source)
        res = self.slam.add_scan(step.stamp, T, step.covariance, step.degraded, level, dbh, z_odom)
        if self.prior is not None and res.keyframe is not None:
            self._place(i, step.stamp, res)
        if self.loops is not None and res.keyframe is not None:
            self.loops.step(self.slam, res.keyframe, res.T_map_sensor)
        if res.keyframe is not None and source is not None:
            self.refiner.add_keyframe(source, res.T_map_sensor)
        ground = getattr(stems, "ground", None) if stems is not None else None
        if res.keyframe is not None and self.ground is not None:
            if ground is not None and len(ground):
                self.ground.add_keyframe(res.keyframe, np.asarray(ground, dtype=np.float64))
        if res.keyframe is not None and self.cloud is not None:
            stem_points = list(stems.points) if k else []
            self.cloud.add_keyframe(
                res.keyframe, step.stamp, scan.points, ground, stem_points, res.landmark_ids + 1
            )
        if k:
            centre_map = transform_points(res.T_map_sensor, centre)
            if self.viewer is not None:
                self.viewer.stems(i, step.stamp, centre_map, dbh)
            self.trees.add(
                i,
                res.T_map_sensor,
                res.landmark_ids,
                list(stems.points),
                np.asarray(stems.base_z, dtype=np.float64),
                centre_map[:, 2],
                dbh,
                np.hypot(stems.xy[:, 0], stems.xy[:, 1]),
                centre_map[:, :2],
            )
        self.trees.add_returns(
            step.stamp, res.T_map_sensor, scan.points, scan.ring, scan.time, T_odom=T
        )
        if i % self.cfg.mapping.dbh_window_scans == 0:
            self.trees.flush(i)

    def _place(self, i: int, stamp: float, res) -> None:
        """Place the run in the prior map: at once with an initial pose, else by global
        localization of its trees (see forestslam.multisession.prior)."""
        if self.prior.placed:
            return
        if self.initial_pose is not None:
            from forestslam.geometry import planar_pose

            T_map_first = planar_pose(*self.initial_pose)  # the first scan's sensor frame
            self.prior.place_at(self.slam, T_map_first, i, stamp)
            return
        self.prior.maybe_place(self.slam, res.keyframe, res.T_map_sensor, i, stamp)

    def _refine_hook(self, T_odom: np.ndarray, source: np.ndarray):
        """Scan-to-map ICP from the SLAM prediction (planar (3,3)) -> planar pose + covariance."""
        from forestslam.slam.landmark_slam import lift, planar, pose2_matrix, tilt

        m = self.cfg.mapping

        def hook(pred: np.ndarray):
            out = self.refiner.refine(source, lift(pred) @ tilt(T_odom))
            if out is None:
                return None
            T, cov6 = out
            cov = cov6[np.ix_([0, 1, 5], [0, 1, 5])]
            floor = np.diag([m.icp_sigma_floor_m**2] * 2 + [np.radians(m.icp_sigma_floor_deg) ** 2])
            if not np.isfinite(cov).all():
                return None
            return pose2_matrix(planar(T)), cov + floor

        return hook

    # ---------------------------------------------------------------- outputs
    def tree_table(self) -> dict:
        """trees.csv in the output frame; `self.tree_ids` maps each landmark to its row's id."""
        xy, nobs = self.slam.landmarks()
        counts = nobs if self.prior is None else self.prior.table_counts(nobs)
        alias = self.slam.aliases()  # trees mapped twice, tied by place recognition: one row
        tied = alias >= 0
        counts = counts.copy()
        np.add.at(counts, alias[tied], counts[tied])
        counts[tied] = 0
        table = self.trees.table(np.arange(len(xy)), xy, counts)
        landmarks = np.asarray(table["id"], dtype=np.int64)
        # tree heights corrected for the odometry's z drift, where the SLAM has them
        heights = self.slam.landmark_heights()[landmarks]
        table["z"] = np.where(np.isfinite(heights), heights, table["z"])
        if self.prior is not None:  # ids, positions, DBH and counts in the prior map
            table = self.prior.express_table(table, self.slam)
        else:
            table["id"] = landmarks + 1  # ids from 1: 0 is "no tree" in map.laz's tree_id
        self.tree_ids = np.zeros(len(xy), dtype=np.int64)
        self.tree_ids[landmarks] = table["id"]
        self.tree_ids[tied] = self.tree_ids[alias[tied]]
        self._last_table = self.frame.table(table)
        return self._last_table

    def _in_output_frame(self, poses: np.ndarray) -> np.ndarray:
        """Poses of the odometry/SLAM frame in the output frame (see OutputFrame)."""
        return self.frame.poses(poses)

    def write(self, final: bool) -> dict:
        from forestslam.io import write_trees_csv, write_trees_geojson, write_tum

        out = self.out_dir
        stamps = np.asarray(self.stamps)
        odom = np.stack(self.odom) if self.odom else np.zeros((0, 4, 4))
        table = None
        if self.slam is not None and self.prior is not None:
            self.prior.refit(self.slam)
        write_tum(out / "odometry.tum", stamps, self._in_output_frame(odom))
        if self.slam is not None:
            if final:
                self.trees.flush(None)
            s, poses = self.slam.trajectory()
            write_tum(out / "trajectory.tum", s, self._in_output_frame(poses))
            table = self.tree_table()
            write_trees_csv(out / "trees.csv", table)
            write_trees_geojson(out / "trees.geojson", table, self.frame.crs_urn())
            self._show_map(s, poses)
        if final:
            self._write_final(stamps, odom, table)
        return table or {}

    def _show_map(self, stamps: np.ndarray, poses: np.ndarray) -> None:
        """The viewer's trajectory and tree map (the run's own frame: Rerun keeps float32)."""
        if self.viewer is None or not len(stamps):
            return
        xy, _ = self.slam.landmarks()
        z = self.slam.landmark_heights()
        self.viewer.trajectory(self.n - 1, stamps[-1], poses[:, :3, 3])
        dbh = np.array([self.trees.dbh(int(j))[0] for j in range(len(xy))])
        self.viewer.trees(self.n - 1, stamps[-1], np.column_stack([xy, np.nan_to_num(z)]), dbh)

    def _write_final(self, stamps, odom, table) -> None:
        from forestslam.io.atomic import atomic_write_text
        from forestslam.mapping.plot import plot_map

        out = self.out_dir
        import json

        atomic_write_text(out / "timing.json", json.dumps(self.timer.to_dict(True), indent=1))
        if self.slam is None:
            return
        s, poses = self.slam.trajectory()
        plot_map(
            out / "map.png",
            self._in_output_frame(poses)[:, :2, 3],
            self._in_output_frame(odom)[:, :2, 3],
            np.column_stack([table["x"], table["y"]]),
            table["dbh_m"],
            title=f"{len(table['id'])} trees, {len(s)} scans ({self.mode})",
        )
        from forestslam.io.gis import write_trees_gpkg

        status = table.get("status", np.full(len(table["id"]), "new", dtype=object))
        write_trees_gpkg(out / "trees.gpkg", {**table, "status": status}, self.frame.crs)
        kf_poses = poses[self.slam.keyframe_scans] if len(poses) else np.zeros((0, 4, 4))
        if self.cloud is not None:
            self._write_map_laz(kf_poses)
        if self.ground is not None:
            self._write_ground(kf_poses)

    def _write_map_laz(self, kf_poses: np.ndarray) -> None:
        """map.laz: the keyframes' clouds placed by the optimised poses, ground and tree ids."""
        from forestslam.io.gis import write_map_laz
        from forestslam.mapping.cloud_map import label_stems

        cloud = self.cloud.build(kf_poses)
        label = cloud["tree_id"].astype(np.int64)  # landmark + 1, 0: none
        ids = np.concatenate([[0], self.tree_ids])[np.minimum(label, len(self.tree_ids))]
        points = self.frame.points(cloud["points"])
        ids = label_stems(points, cloud["classification"], ids, self._last_table)
        write_map_laz(
            self.out_dir / "map.laz",
            points,
            cloud["classification"],
            ids,
            cloud["time"],
            self.frame.crs,
        )

    def _write_ground(self, kf_poses: np.ndarray) -> None:
        from forestslam.io import write_cloud
        from forestslam.mapping import dtm_grid, write_dtm
        from forestslam.mapping.plot import plot_dtm

        ground = self.ground.build(kf_poses)  # voxels in the run's own frame, near its origin
        if self.viewer is not None:
            self.viewer.ground(self.n - 1, self.stamps[-1], ground)
        ground = self.frame.points(ground)  # then moved, in float64, into the output frame
        write_cloud(self.out_dir / "ground.ply", ground)
        m = self.cfg.mapping
        dtm = dtm_grid(ground, m.dtm_cell_m, m.dtm_min_points, m.dtm_window_m, m.dtm_max_raise_m)
        write_dtm(self.out_dir, dtm)
        plot_dtm(self.out_dir / "dtm.png", dtm)


def run(
    input_path: str | Path,
    sensor: str | None,
    out_dir: str | Path,
    mode: str = "slam",
    config: Any = None,
    config_path: str | Path | None = None,
    start: int = 0,
    max_scans: int | None = None,
    topic: str | None = None,
    progress: bool = True,
    overwrite: bool = False,
    prior_map: str | Path | None = None,
    initial_pose: str | None = None,
    inject_drift: str | None = None,
    crs: str | None = None,
    georef: str | None = None,
    rerun: bool = False,
    rerun_save: str | Path | None = None,
) -> RunSummary:
    """Run the pipeline on a bag / folder / file and write the outputs into `out_dir`.
    `sensor` None: identified from the first scans (forestslam.sensors.identify).
    `prior_map` (a tree CSV, saved map or run directory) starts the run in that map; an
    `initial_pose` "x,y,yaw_deg" of the first scan in the map skips the search;
    `inject_drift` "scale,yaw_deg_per_10m" corrupts the odometry (tests and benches).
    `crs` (EPSG:N ...) with a prior map in it, or with `georef` "x,y,z,yaw_deg" (the first
    scan's pose in it): every output in that CRS. `rerun` / `rerun_save`: a live view.

    The output directory is owned as `forestslam.job` describes (lock, an earlier run's outputs
    replaced or refused, run.yaml with the outcome)."""
    from forestslam.config import load_config
    from forestslam.config_utils import validate
    from forestslam.job import Job, ScanWindow

    if mode not in MODES:
        raise InputError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")
    window = ScanWindow(start, max_scans)
    cfg = validate(config) if config is not None else load_config(config_path)
    profile, stream, scans, count = _open_scans(window, input_path, topic, sensor)
    prior, pose, drift = _multisession(cfg, prior_map, initial_pose, inject_drift)
    options = RunOptions(prior, pose, drift, Georeference.from_options(crs, georef))
    if rerun or rerun_save is not None:
        from forestslam.viewer import RerunView

        options.viewer = RerunView(spawn=rerun, save=rerun_save)
    meta = _run_meta(input_path, topic, profile, sensor is None, mode, window, cfg)
    with Job("run", out_dir, meta, inputs=[input_path, config_path], overwrite=overwrite) as job:
        pipe = Pipeline(profile, cfg, mode, job.out, options)
        job.meta["output_frame"] = pipe.frame.to_dict()
        summary = RunSummary(out_dir=job.out, mode=mode)
        _process_scans(pipe, scans, count, stream, job, summary, progress, input_path)
    summary.status = job.status
    return summary


def _open_scans(window, input_path, topic, sensor):
    """(profile, stream, scans, count) of the window; the sensor identified from the first
    scans when `sensor` is None."""
    from forestslam.sensors import load_profile

    profile = load_profile(sensor) if sensor is not None else None
    packets = profile.packet_config() if profile is not None else None
    stream, scans, count = window.open(input_path, topic, packets)  # `start` skipped undecoded
    if profile is None:
        from forestslam.sensors.identify import identify_stream

        profile, scans = identify_stream(scans)
    return profile, stream, scans, count


def _run_meta(input_path, topic, profile, identified: bool, mode: str, window, cfg) -> dict:
    """run.yaml's description of the run (its summary is added as it goes)."""
    from forestslam.config import config_to_dict

    return {
        "input": str(input_path),
        "topic": topic,
        "sensor": profile.name,
        "sensor_identified": identified,
        "mode": mode,
        **window.meta(),
        "versions": _versions(),
        "config": config_to_dict(cfg),
    }


def _process_scans(pipe, scans, count, stream, job, summary, progress: bool, input_path) -> None:
    """The scan loop with its progress and checkpoints; the final outputs and run.yaml summary
    are written however it ends."""
    from forestslam.job import Checkpoints, Progress

    checkpoints = Checkpoints(pipe.cfg.mapping.checkpoint_every_scans)
    bar = Progress(count, "scan", "run", enabled=progress)
    t0, c0 = time.perf_counter(), time.process_time()

    def update_summary() -> None:
        summary.wall_s = time.perf_counter() - t0
        summary.scans = pipe.n
        summary.failed_scans = pipe.failed
        summary.degraded_scans = pipe.degraded
        summary.scans_per_s = pipe.n / summary.wall_s if summary.wall_s > 0 else 0.0
        summary.cpu_s = time.process_time() - c0
        summary.cpu_scans_per_s = pipe.n / summary.cpu_s if summary.cpu_s > 0 else 0.0
        summary.read_stats = stream.stats.to_dict()
        job.summary = summary.to_dict()
        _record_multisession(job, pipe)

    try:
        for scan in scans:
            pipe.process(scan)
            trees = {"trees": pipe.slam.n_landmarks} if pipe.slam is not None else {}
            bar.update(1, **trees)
            if checkpoints.due(pipe.n):
                pipe.write(final=False)
                update_summary()  # a killed run's run.yaml then has counts up to here
                job.write_meta()
        if pipe.n == 0:
            raise InputError(f"{input_path}: no scan could be processed")
    finally:
        bar.close()
        update_summary()
        _finish(pipe, summary)
        job.summary = summary.to_dict()
        _record_multisession(job, pipe)  # after the final refit of the placement
        job.meta["output_frame"] = pipe.frame.to_dict()
        if pipe.viewer is not None:
            pipe.viewer.close()


def _multisession(cfg, prior_map, initial_pose, inject_drift):
    """(prior map, initial pose in its local frame, drift injector), each None when not asked."""
    prior = pose = drift = None
    if initial_pose is not None and prior_map is None:
        raise InputError("--initial-pose places the run in a prior map: give --prior-map too")
    if prior_map is not None:
        from forestslam.multisession.prior import load_prior_map, parse_initial_pose

        prior = load_prior_map(prior_map, cfg.prior_map)
        _warn_if_incomplete(prior_map)
        if initial_pose is not None:
            pose = parse_initial_pose(initial_pose)
            pose[:2] -= prior.origin
            _check_initial_pose_near(pose, prior.xy, initial_pose)
    if inject_drift is not None:
        from forestslam.multisession.drift import DriftInjector

        drift = DriftInjector.parse(inject_drift)
    return prior, pose, drift


def _warn_if_incomplete(prior_map) -> None:
    """A prior map that is a run directory whose run did not complete: its last checkpoint."""
    from forestslam.job import run_status

    status, error = run_status(prior_map) if Path(prior_map).is_dir() else (None, None)
    if status not in (None, "complete"):
        why = f" ({error})" if error else ""
        log.warning("--prior-map %s: run.yaml says status: %s%s; using its last checkpoint",
                    prior_map, status, why)  # fmt: skip


MAX_START_FROM_MAP_M = 500.0  # farther from every prior tree, the scans cannot see the map


def _check_initial_pose_near(pose: np.ndarray, map_xy: np.ndarray, text: str) -> None:
    """--initial-pose in another frame than the map (local vs UTM, swapped x/y) is refused."""
    gap = float(np.min(np.linalg.norm(map_xy - pose[:2], axis=1)))
    if gap > MAX_START_FROM_MAP_M:
        raise InputError(
            f"--initial-pose {text}: {gap:.0f} m from the nearest tree of the prior map; give "
            "x,y in the map's coordinates (the frame of its x, y columns)"
        )


def _record_multisession(job, pipe: Pipeline) -> None:
    """run.yaml: how the run was placed in its prior map, and what place recognition did."""
    if pipe.prior is not None:
        job.meta["prior_map"] = pipe.prior.to_dict()
    if pipe.loops is not None:
        job.meta["place_recognition"] = dict(pipe.loops.stats)
    if pipe.slam is not None:  # tracking losses (odometry jumps) and declined moves (revisits)
        recognition = job.meta.setdefault("place_recognition", {})
        recognition["tracking_losses"] = pipe.slam.losses
        recognition["revisits"] = pipe.slam.revisits


def _finish(pipe: Pipeline, summary: RunSummary) -> None:
    """Final outputs and counts of a run, whatever its outcome (the Job records the status)."""
    if pipe.n:
        table = pipe.write(final=True)
        summary.trees = len(table.get("id", []))
    if pipe.slam is not None:
        summary.keyframes = pipe.slam.n_keyframes
        summary.loop_closures = pipe.slam.loop_closures
        summary.reassociation_corrections = pipe.slam.reassociation_corrections
        summary.failed_updates = pipe.slam.failed_updates
    if pipe.refiner is not None:
        summary.icp_accepted = pipe.refiner.accepted
        summary.icp_rejected = pipe.refiner.rejected
