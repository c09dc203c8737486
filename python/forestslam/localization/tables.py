"""Tree tables of other mappers (RealtimeTrees / TreeLoc layout) as a map source and as queries.

A map: every frame's trees moved into the world frame by the table's reference trajectory,
detections of one tree from many frames merged. A query: one frame's trees, levelled (by the
reference gravity when asked, otherwise by the frame's own stem axes) and projected to the plane;
the local frame of the query is the levelled frame of pose k.
"""

from __future__ import annotations

import logging

import numpy as np

from forestslam.errors import InputError
from forestslam.geometry import pose3, rot_z, transform_points, yaw_of
from forestslam.io.tree_tables import TreeTable, level_rotation

log = logging.getLogger(__name__)


def table_map_xy(
    table: TreeTable,
    merge_radius_m: float = 0.3,
    min_frames: int = 2,
    keyframe_distance_m: float = 5.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(M,2) world positions and (M,) DBH of the trees of a table. A frame's table is the local
    map around its pose, so frames at least ``keyframe_distance_m`` apart suffice (each tree
    is still in several). Detections closer than ``merge_radius_m`` are one tree; trees in
    fewer than ``min_frames`` of those frames (transient false trees) are dropped."""
    from forestslam.localization.localize import merge_close

    if table.poses is None:
        raise InputError("a tree table needs its trajectory (trajectory.txt/.tum) to be a map")
    frames, last = [], None
    for k in table.frames:
        p = table.poses[int(k)][:2, 3]
        if last is None or np.hypot(*(p - last)) >= keyframe_distance_m:
            frames.append(int(k))
            last = p
    parts, dbhs, ids = [], [], []
    for k in frames:
        rows = table.rows(int(k))
        T = table.poses[int(k)]
        parts.append(transform_points(T, table.xyz[rows]))
        dbhs.append(table.dbh_m[rows])
        ids.append(np.full(len(rows), k))
    if not parts:
        raise InputError("tree table holds no trees")
    xy = np.concatenate(parts)[:, :2]
    centres, labels = merge_close(xy, merge_radius_m, return_labels=True)
    frame_of = np.concatenate(ids)
    seen = np.zeros(len(centres))
    pairs = np.unique(np.column_stack([labels, frame_of]), axis=0)
    np.add.at(seen, pairs[:, 0], 1)
    dbh_all = np.concatenate(dbhs)
    dbh = np.full(len(centres), np.nan)
    ok = np.isfinite(dbh_all)
    if ok.any():
        sums = np.bincount(labels[ok], dbh_all[ok], minlength=len(centres))
        counts = np.bincount(labels[ok], minlength=len(centres))
        dbh = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    keep = seen >= min(min_frames, len(frames))
    log.info("tree table map: %d trees from %d frames", keep.sum(), len(frames))
    return centres[keep], dbh[keep]


def reference_level(T_world_frame: np.ndarray) -> np.ndarray:
    """R_level_frame from a reference pose: the rotation that removes its roll and pitch."""
    R = np.asarray(T_world_frame, dtype=np.float64)[:3, :3]
    return rot_z(float(yaw_of(R))).T @ R


def query_xy(
    table: TreeTable, k: int, gravity: str = "stems", max_range_m: float = 40.0
) -> tuple[np.ndarray, np.ndarray]:
    """Levelled (K,2) trees of frame k and R_level_frame (3,3). ``gravity``: "stems" (the
    frame's stem axes; identity when fewer than 3 are known), "reference" (the table's
    trajectory) or "none"."""
    xy, _dbh, R = query_trees(table, k, gravity, max_range_m)
    return xy, R


def query_trees(
    table: TreeTable, k: int, gravity: str = "stems", max_range_m: float = 40.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``query_xy`` with the trees' DBH (K,) (m, NaN where not fitted) beside them."""
    rows = table.rows(int(k))
    xyz = table.xyz[rows]
    if gravity == "reference":
        if table.poses is None:
            raise InputError("gravity 'reference' needs the table's trajectory")
        R = reference_level(table.poses[int(k)])
    elif gravity == "stems":
        R = level_rotation(table.axis[rows])
        R = np.eye(3) if R is None else R
    elif gravity == "none":
        R = np.eye(3)
    else:
        raise InputError(f"gravity must be stems, reference or none, not {gravity!r}")
    xy = transform_points(pose3(R), xyz)[:, :2]
    near = np.hypot(xy[:, 0], xy[:, 1]) <= max_range_m
    return xy[near], np.asarray(table.dbh_m[rows], dtype=np.float64)[near], R


def true_planar_pose(table: TreeTable, k: int, R_level: np.ndarray) -> tuple[float, float, float]:
    """Reference (x, y, yaw) of the levelled frame of pose k in the world frame."""
    T = table.poses[int(k)]
    return float(T[0, 3]), float(T[1, 3]), float(yaw_of(T[:3, :3] @ R_level.T))


def run_table_localization(
    trees_path,
    tree_map,
    out_dir,
    every: int = 1,
    config_path=None,
    gravity: str = "stems",
    start: int = 0,
    max_queries: int | None = None,
    overwrite: bool = False,
):
    """Localize every ``every``-th frame of a tree table in ``tree_map`` as a `localize` job
    (lock, run.yaml, outputs: see ``forestslam.job``); writes ``localization.json`` and
    ``localization.tum`` like ``run_localization`` (the pose written is the levelled frame of
    pose k in the map frame; ``stamp`` from the table's trajectory, else the frame index). The
    table's DBH goes with each query (evidence when the map has DBH too)."""
    from forestslam.config_utils import to_dict
    from forestslam.io.tree_tables import read_tree_table
    from forestslam.localization.localize import localize
    from forestslam.localization.runner import (
        LocalizationRun,
        _load_config,
        _open_map,
        _query_record,
        map_meta,
        run_localize_job,
    )

    if every < 1:
        raise InputError(f"--every must be >= 1 (got {every})")
    if start < 0:
        raise InputError(f"--start must be >= 0 (got {start})")
    if gravity not in ("stems", "reference", "none"):
        raise InputError(f"gravity must be stems, reference or none, not {gravity!r}")
    _root, cfg = _load_config(config_path)
    table = read_tree_table(trees_path)
    the_map = _open_map(tree_map)
    frames = table.frames[start::every][:max_queries]
    meta = {
        "input": str(trees_path),
        **map_meta(tree_map, the_map),
        "every": every,
        "start": start,
        "max_queries": max_queries,
        "gravity": gravity,
        "frame": "pose of the levelled frame k in the map frame (planar x, y, yaw)",
        "config": {"localization": to_dict(cfg)},
    }

    def loop(run: LocalizationRun) -> None:
        for k in frames:
            # The table's DBH is evidence when the map has DBH too (config dbh_evidence).
            local, local_dbh, _R = query_trees(table, int(k), gravity, cfg.max_range_m)
            loc = localize(the_map, local, cfg, local_dbh)
            stamp = float(table.stamps[k]) if table.stamps is not None else float(k)
            run.scans += 1
            run.queries.append(_query_record(stamp, int(k), len(local), loc))
            run.query_done()

    inputs = [trees_path, config_path, tree_map]
    # every 100th query: rewriting all queries after each would be O(n^2) over long tables
    return run_localize_job(out_dir, meta, inputs, overwrite, loop, checkpoint_every=100)
