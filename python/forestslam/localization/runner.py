"""Global localization along a recorded sequence: a query every K scans from the last N scans.

Stems come from `forestslam.perception.detect` (one frame) or from the odometry steps
(`forestslam.odometry.Odometry`, several frames aggregated in the last scan's frame). Every
query is appended to ``localization.json``; accepted ones give the sensor pose in the map frame
in ``localization.tum``. Both files are rewritten atomically after every query, so a killed run
leaves valid files up to its last query.

With ``keyframe_distance_m`` > 0 the N frames of a query are the current scan and the N-1 latest
earlier scans at least that far apart (a wider view); 0 means the last N scans.

With ``retry_frames`` R > N (``localization.retry_frames``, 5 by default), a rejected query is
tried once more on the last R frames at least ``retry_keyframe_distance_m`` (3 m) apart (as many
as the sequence has given so far), aggregated by odometry like N: the machine told "rejected"
waits for more trunks, and these are the trunks it has already driven past. Still rejected, it
is tried a last time on up to ``retry_last_frames`` (7: 18 m of driving) when the sequence has
given more. Each look is another chance to accept an absent place, so every look of such a query
is tested at ``chain_significance(min_significance, looks)``. The record says which answer it
is: ``retried``, ``frames`` (the frames of the answer), ``looks`` (tests made) and
``first_reason`` (why the N-frame query was rejected; "" when not retried); run.yaml's summary
counts the retried.
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from forestslam.errors import InputError, ProcessingError
from forestslam.geometry import planar_pose
from forestslam.localization.config import LocalizationConfig
from forestslam.localization.localize import (
    Localization,
    aggregate_stems,
    chain_significance,
    localize,
)
from forestslam.localization.tree_map import TreeMap, load_map

log = logging.getLogger(__name__)


@dataclass
class LocalizationRun:
    out_dir: Path
    scans: int = 0
    queries: list[dict] = field(default_factory=list)
    wall_s: float = 0.0
    # Called after every query: the job's checkpoint when one is due (run_localize_job).
    query_done: Callable[[], None] = lambda: None

    @property
    def accepted(self) -> int:
        return sum(1 for q in self.queries if q["accepted"])

    @property
    def median_query_ms(self) -> float:
        return float(np.median([q["time_ms"] for q in self.queries])) if self.queries else 0.0


def _query_record(
    stamp: float,
    scan: int,
    trunks: int,
    loc: Localization,
    frames: int = 1,
    first_reason: str = "",
    retried: bool = False,
    looks: int = 1,
) -> dict:
    return {
        "stamp": float(stamp),
        "scan": int(scan),
        "frames": int(frames),
        "retried": bool(retried),
        "looks": int(looks),
        "first_reason": first_reason,
        "accepted": loc.accepted,
        "x": float(loc.x),
        "y": float(loc.y),
        "yaw": float(loc.yaw),
        "inliers": int(loc.inliers),
        "second_inliers": int(loc.second_inliers),
        "stage": loc.stage,
        "significance": float(loc.significance),
        "runner_up": loc.to_dict()["runner_up"],
        "trunks": int(trunks),
        "rms_m": float(loc.rms_m),
        "covariance": np.asarray(loc.covariance, dtype=float).tolist(),
        "reason": loc.reason,
        "time_ms": float(loc.time_ms),
    }


def _write_outputs(run: LocalizationRun, meta: dict) -> None:
    from forestslam.io import write_tum
    from forestslam.io.atomic import atomic_write_text

    doc = dict(meta)
    doc["queries"] = run.queries
    doc["accepted"] = run.accepted
    atomic_write_text(run.out_dir / "localization.json", json.dumps(doc, indent=1) + "\n")
    acc = [q for q in run.queries if q["accepted"]]
    poses = np.array([planar_pose(q["x"], q["y"], q["yaw"]) for q in acc]).reshape(-1, 4, 4)
    write_tum(run.out_dir / "localization.tum", np.array([q["stamp"] for q in acc]), poses)


def _load_config(config_path, keyframe_distance_m: float | None = None):
    """(root config or None, LocalizationConfig): the file's when given, else the defaults;
    ``keyframe_distance_m`` (the CLI option) overrides the file."""
    from forestslam.config_utils import validate

    root = None
    if config_path is not None:  # the root config imports every component's config: lazily
        from forestslam.config import load_config

        root = load_config(config_path)
    cfg: LocalizationConfig = getattr(root, "localization", None) or LocalizationConfig()
    if keyframe_distance_m is not None:
        cfg.keyframe_distance_m = keyframe_distance_m
    validate(cfg, "localization")
    return root, cfg


def _open_map(map_path: str | Path | TreeMap) -> TreeMap:
    """The prior map (a TreeMap as is, else loaded); fewer than 3 trees is an InputError."""
    tree_map = map_path if isinstance(map_path, TreeMap) else load_map(map_path)
    if len(tree_map) < 3:
        raise InputError(f"{map_path}: the map holds {len(tree_map)} trees; at least 3 needed")
    return tree_map


def map_meta(map_path: str | Path | TreeMap, tree_map: TreeMap) -> dict:
    """The map's entries of ``localization.json`` / ``run.yaml``."""
    in_memory = isinstance(map_path, TreeMap)
    return {"map": "(in memory)" if in_memory else str(map_path), "map_trees": len(tree_map)}


def run_localize_job(
    out_dir, meta: dict, inputs: list, overwrite: bool, loop, checkpoint_every: int = 1
) -> LocalizationRun:
    """The common job skeleton of `localize` (bags and tree tables): lock, run.yaml, a
    checkpoint every `checkpoint_every` queries (the outputs and run.yaml's summary rewritten,
    so a killed run leaves valid files up to it), the same once more at the end (also after an
    error). ``loop(run)`` appends the queries and calls ``run.query_done()`` after each."""
    from forestslam.job import Checkpoints, Job

    with Job("localize", out_dir, meta, inputs=inputs, overwrite=overwrite) as job:
        run = LocalizationRun(job.out)
        checkpoints = Checkpoints(checkpoint_every)
        t0 = time.perf_counter()

        def summarize() -> None:
            run.wall_s = time.perf_counter() - t0
            job.summary = {
                "scans": run.scans,
                "queries": len(run.queries),
                "accepted": run.accepted,
                "retried": sum(bool(q.get("retried")) for q in run.queries),
                "wall_s": round(run.wall_s, 3),
            }

        def query_done() -> None:
            if checkpoints.due(len(run.queries)):
                summarize()
                job.checkpoint(lambda: _write_outputs(run, meta))

        run.query_done = query_done
        try:
            loop(run)
        finally:
            summarize()
            _write_outputs(run, meta)
    return run


def run_localization(
    input_path: str | Path,
    map_path: str | Path | TreeMap,
    sensor: str,
    out_dir: str | Path,
    frames: int = 1,
    every: int = 1,
    config_path: str | Path | None = None,
    topic: str | None = None,
    start: int = 0,
    max_scans: int | None = None,
    progress: bool = False,
    keyframe_distance_m: float | None = None,
    overwrite: bool = False,
    retry_frames: int | None = None,
) -> LocalizationRun:
    """Localize along the scans of ``input_path`` in the map; writes the two output files.

    The local frame of a query is the sensor frame of its last scan; the pose written is that
    sensor's planar pose (x, y, yaw; z, roll and pitch zero) in the map frame. ``retry_frames``
    > ``frames``: a rejected query is retried once on up to that many frames (0: never; None:
    ``localization.retry_frames`` of the config, off when not above ``frames``).
    """
    from forestslam.config_utils import to_dict
    from forestslam.job import Progress, ScanWindow
    from forestslam.sensors import load_profile

    if frames < 1 or every < 1:
        raise InputError(f"--frames and --every must be >= 1 (got {frames}, {every})")
    if retry_frames is not None and retry_frames != 0 and retry_frames <= frames:
        raise InputError(
            f"--retry-frames must be 0 (off) or more than --frames (got {retry_frames}, {frames})"
        )
    window = ScanWindow(start, max_scans)
    root, cfg = _load_config(config_path, keyframe_distance_m)
    if retry_frames is None:  # the config's, off when it asks for no more than a query has
        retry_frames = cfg.retry_frames if cfg.retry_frames > frames else 0
    retry_last = cfg.retry_last_frames if 0 < retry_frames < cfg.retry_last_frames else 0
    profile = load_profile(sensor)
    tree_map = _open_map(map_path)
    # `start` skipped undecoded; raw Velodyne packets decoded as the profile says
    stream, scans, count = window.open(input_path, topic, profile.packet_config())
    meta = {
        "input": str(input_path),
        **map_meta(map_path, tree_map),
        "sensor": profile.name,
        "frames": frames,
        "retry_frames": retry_frames,
        "retry_last_frames": retry_last,
        "retry_keyframe_distance_m": cfg.retry_keyframe_distance_m,
        "every": every,
        "keyframe_distance_m": cfg.keyframe_distance_m,
        **window.meta(),
        "frame": "pose of the last scan's sensor in the map frame (planar x, y, yaw)",
        "config": {"localization": to_dict(cfg)},
    }
    query = _QuerySetup(tree_map, profile, root, cfg, frames, every, meta, retry_frames, retry_last)

    def loop(run: LocalizationRun) -> None:
        bar = Progress(count, "scan", "localize", enabled=progress)
        try:
            _localize_along(scans, window.start, query, run, bar)
        finally:
            bar.close()

    inputs = [input_path, config_path, map_path]
    return run_localize_job(out_dir, meta, inputs, overwrite, loop)


@dataclass(frozen=True)
class _QuerySetup:
    """What every query along a sequence shares."""

    tree_map: TreeMap
    profile: object
    root: object
    cfg: LocalizationConfig
    frames: int
    every: int
    meta: dict
    retry_frames: int = 0  # > frames: a rejected query is retried on up to this many frames
    retry_last_frames: int = 0  # > retry_frames: still rejected, once more on up to this many

    @property
    def needs_odometry(self) -> bool:
        """Frames aggregated: a query of several frames, or a retry."""
        return max(self.frames, self.retry_frames) > 1

    @property
    def looks(self) -> int:
        """Tests a query may get: the first, the retry, the last retry."""
        return 1 + (self.retry_frames > 0) + (self.retry_last_frames > 0)

    @property
    def look_config(self) -> LocalizationConfig:
        """The config of every look: the significance level spent across the looks."""
        return replace(
            self.cfg, min_significance=chain_significance(self.cfg.min_significance, self.looks)
        )


class _Keyframes:
    """The last `size` earlier frames (stems (K,2), T_world_sensor (4,4)), each at least
    `distance_m` from the one before."""

    def __init__(self, size: int, distance_m: float) -> None:
        self.frames: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max(size, 0))
        self.distance_m = distance_m

    def offer(self, xy: np.ndarray, T: np.ndarray) -> None:
        if self.frames.maxlen and (
            not self.frames
            or np.linalg.norm(T[:2, 3] - self.frames[-1][1][:2, 3]) >= self.distance_m
        ):
            self.frames.append((xy, T))


def _make_odometry(q: _QuerySetup):
    """Odometry for aggregated queries (frames or retry_frames > 1), else None."""
    if not q.needs_odometry:
        return None
    try:
        from forestslam.odometry import Odometry
    except ImportError as exc:
        raise ProcessingError(
            f"{max(q.frames, q.retry_frames)} frames per query need odometry, not available: {exc}"
        ) from exc
    return Odometry(
        q.profile, getattr(q.root, "odometry", None), getattr(q.root, "perception", None)
    )


def _localize_along(scans, first: int, q: _QuerySetup, run: LocalizationRun, bar) -> None:
    """The query loop: stems per scan (odometry when several frames), a query when due."""
    from forestslam.perception import detect

    odometry = _make_odometry(q)
    # Earlier frames (keyframes at least keyframe_distance_m apart, the retry's at least
    # retry_keyframe_distance_m); the current scan is always the last frame of a query.
    window = _Keyframes(q.frames - 1, q.cfg.keyframe_distance_m)
    retry_window = _Keyframes(
        max(q.retry_frames, q.retry_last_frames) - 1, q.cfg.retry_keyframe_distance_m
    )
    for i, scan in enumerate(scans, start=first):
        run.scans += 1
        bar.update(1, queries=len(run.queries), accepted=run.accepted)
        # First query when the window is full, then every `every` scans.
        due = run.scans >= q.frames and (run.scans - q.frames) % q.every == 0
        if odometry is not None:  # every scan: odometry needs them all
            step = odometry.step(scan)
            stems, T = step.stems, np.asarray(step.T_world_sensor, dtype=np.float64)
        elif due:  # one frame per query: only query scans need stems
            stems, T = detect(scan, q.profile, getattr(q.root, "perception", None)), np.eye(4)
        else:
            continue
        xy = np.zeros((0, 2)) if stems is None else np.asarray(stems.xy, dtype=np.float64)
        record = None
        if due and len(window.frames) >= q.frames - 1:
            record = _query(q, list(window.frames), list(retry_window.frames), xy, T, scan, i)
        window.offer(xy, T)
        retry_window.offer(xy, T)
        if record is None:
            continue
        run.queries.append(record)
        run.query_done()


def _query(
    q: _QuerySetup, earlier: list, retry_earlier: list, xy: np.ndarray, T: np.ndarray, scan, i
) -> dict:
    """The record of one query (scan `scan`, number i): the current scan and the last frames - 1
    earlier frames; when rejected and the retry's keyframes hold more than that, once more on the
    current scan and up to retry_frames - 1 earlier ones; still rejected and holding more, a
    last time on up to retry_last_frames - 1 (every look at the level spent across the looks)."""
    config = q.look_config

    def attempt(frames: list) -> tuple[Localization, int, int]:
        local, seen = aggregate_stems(
            [f[0] for f in frames] + [xy], [f[1] for f in frames] + [T], q.cfg, True
        )
        return localize(q.tree_map, local, config, observations=seen), len(local), len(frames) + 1

    def last(frames: int) -> list:
        return retry_earlier[max(len(retry_earlier) - (frames - 1), 0) :] if frames > 1 else []

    loc, trunks, used = attempt(earlier[len(earlier) - (q.frames - 1) :] if q.frames > 1 else [])
    first_reason, looks = "", 1
    for frames in (q.retry_frames, q.retry_last_frames):
        if not (loc.rejected and frames and len(last(frames)) >= used):
            break
        first_reason = first_reason or loc.reason
        loc, trunks, used = attempt(last(frames))
        looks += 1
        log.debug("scan %d: rejected (%s), retried on %d frames", i, first_reason, used)
    return _query_record(scan.stamp, i, trunks, loc, used, first_reason, looks > 1, looks)
