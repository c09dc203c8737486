"""The registered point-cloud map (map.laz): every keyframe's scan, voxel-thinned, labelled.

Like the ground map, points are kept per keyframe in its sensor frame and placed with the
*optimised* keyframe poses when the map is written, so loop closures move them with the
trajectory. Each voxel is labelled from the keyframe's perception: ground (ASPRS class 2) where a
ground point falls in it, the tree map's id where a stem point of an associated stem does (0
elsewhere). Memory is bounded by the keyframe voxel size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from forestslam.geometry import column_bounds, transform_points
from forestslam.io.gis import GROUND, UNCLASSIFIED
from forestslam.mapping.voxel import voxel_downsample, voxel_keys


@dataclass
class _Keyframe:
    index: int
    stamp: float
    points: np.ndarray  # (N,3) float32, sensor frame
    ground: np.ndarray  # (N,) bool
    tree_id: np.ndarray  # (N,) uint32, 0: no stem


class CloudMap:
    def __init__(self, keyframe_voxel_m: float = 0.1, voxel_m: float = 0.1) -> None:
        self.keyframe_voxel_m = keyframe_voxel_m
        self.voxel_m = voxel_m
        self._keyframes: list[_Keyframe] = []

    def __len__(self) -> int:
        return len(self._keyframes)

    def add_keyframe(
        self,
        keyframe: int,
        stamp: float,
        points: np.ndarray,
        ground_points: np.ndarray | None = None,
        stem_points: list[np.ndarray] | None = None,
        stem_tree_ids: np.ndarray | None = None,
    ) -> None:
        """A keyframe's scan points (N,3) in its sensor frame, with its ground points and its
        stems' points (one (M,3) array per stem) and their tree ids (>= 1; 0 for a stem the map
        did not keep)."""
        v = self.keyframe_voxel_m
        pts = voxel_downsample(points, v)
        keys = voxel_keys(pts, v)
        ground = np.zeros(len(pts), dtype=bool)
        if ground_points is not None and len(ground_points):
            ground = _isin(keys, voxel_keys(np.asarray(ground_points, np.float64), v))
        tree_id = _stem_ids(keys, v, stem_points or [], stem_tree_ids)
        self._keyframes.append(_Keyframe(keyframe, stamp, pts.astype(np.float32), ground, tree_id))

    def build(self, keyframe_poses: np.ndarray) -> dict[str, np.ndarray]:
        """The map in the poses' frame: points (M,3) float64, classification, tree_id, time
        (the stamp of the keyframe each voxel's points came from, the latest where several)."""
        parts = [kf for kf in self._keyframes if kf.index < len(keyframe_poses)]
        if not parts:
            return _empty()
        pts = np.concatenate(
            [transform_points(keyframe_poses[kf.index], kf.points) for kf in parts]
        )
        ground = np.concatenate([kf.ground for kf in parts])
        tree = np.concatenate([kf.tree_id for kf in parts])
        stamp = np.repeat([kf.stamp for kf in parts], [len(kf.points) for kf in parts])
        origin = column_bounds(pts)[0]  # voxel keys near the origin, whatever the offsets
        # Points grouped by voxel (the C++ core's radix sort of compact voxel keys: the order of
        # a sort of the packed keys, in half numpy's argsort CPU), so the per-voxel maxima are
        # reductions over contiguous runs (np.maximum.at per point cost 0.3 s on 600 scans). The
        # order inside a run does not matter (maxima; the sums below go in point order).
        from forestslam import _core

        groups = _core.group_by_voxel(pts, origin, self.voxel_m)
        order, start, inverse = groups.order, groups.start, groups.inverse
        m = len(start)
        counts = np.bincount(inverse, minlength=m)
        centroid = (
            np.column_stack(
                [np.bincount(inverse, weights=pts[:, k] - origin[k], minlength=m) for k in range(3)]
            )
            / counts[:, None]
            + origin
        )
        is_ground = np.bincount(inverse, weights=ground, minlength=m) > 0
        tree_id = np.maximum.reduceat(tree[order], start).astype(np.uint32)
        time = np.maximum.reduceat(stamp[order], start)
        return {
            "points": centroid,
            "classification": np.where(is_ground, GROUND, UNCLASSIFIED).astype(np.uint8),
            "tree_id": tree_id,
            "time": time,
        }


def _stem_ids(keys: np.ndarray, voxel_m: float, stems: list, ids) -> np.ndarray:
    """(N,) uint32 tree id of the voxels `keys` holding a stem's points (0: none); one sorted
    lookup for all stems (where two stems share a voxel, the later one's id)."""
    out = np.zeros(len(keys), dtype=np.uint32)
    ids = np.zeros(0, dtype=np.int64) if ids is None else np.asarray(ids).ravel()
    if len(stems) != len(ids):
        raise ValueError(f"{len(stems)} stems for {len(ids)} tree ids")
    use = [k for k in range(len(stems)) if ids[k] > 0 and len(stems[k])]
    if not use:
        return out
    points = np.concatenate([np.asarray(stems[k], np.float64).reshape(-1, 3) for k in use])
    stem_keys = voxel_keys(points, voxel_m)
    stem_ids = np.repeat(ids[use].astype(np.uint32), [len(stems[k]) for k in use])
    order = np.argsort(stem_keys, kind="stable")
    stem_keys, stem_ids = stem_keys[order], stem_ids[order]
    last = np.searchsorted(stem_keys, keys, side="right") - 1  # the latest stem in a voxel
    hit = (last >= 0) & (stem_keys[np.maximum(last, 0)] == keys)
    out[hit] = stem_ids[last[hit]]
    return out


def _isin(keys: np.ndarray, of: np.ndarray) -> np.ndarray:
    """np.isin(keys, of) for int64 keys by a binary search in the sorted `of` (np.isin sorts
    both arrays together: 4x the CPU on a keyframe's voxels)."""
    if len(of) == 0:
        return np.zeros(len(keys), dtype=bool)
    of = np.sort(of)
    at = np.minimum(np.searchsorted(of, keys), len(of) - 1)
    return of[at] == keys


def _empty() -> dict[str, np.ndarray]:
    return {
        "points": np.zeros((0, 3)),
        "classification": np.zeros(0, dtype=np.uint8),
        "tree_id": np.zeros(0, dtype=np.uint32),
        "time": np.zeros(0),
    }


def label_stems(
    points: np.ndarray,
    classification: np.ndarray,
    tree_id: np.ndarray,
    trees: dict,
    margin_m: float = 0.1,
    below_m: float = 1.3,
    above_m: float = 2.7,
) -> np.ndarray:
    """Tree ids completed geometrically: a non-ground point within a tree's stem radius
    (DBH / 2, 0.15 m when unknown) plus `margin_m` of its axis, from `below_m` under to
    `above_m` over its breast-height centre, takes the tree's id where perception left it
    unlabelled (a stem seen before it became a tree, or at a scan between keyframes)."""
    from scipy.spatial import cKDTree

    ids = np.asarray(tree_id).copy()
    if not len(trees.get("x", [])) or not len(points):
        return ids
    xy = np.column_stack([trees["x"], trees["y"]])
    dbh = np.asarray(trees["dbh_m"], dtype=np.float64)
    radius = np.where(np.isfinite(dbh), dbh / 2, 0.15) + margin_m
    z = np.asarray(trees["z"], dtype=np.float64)
    free = np.flatnonzero((ids == 0) & (classification != GROUND))
    reach = float(radius.max())
    free = free[_maybe_near(points[free, :2], xy, reach)]  # the query's certain misses dropped
    dist, k = cKDTree(xy).query(points[free, :2], distance_upper_bound=reach)
    hit = np.isfinite(dist)
    free, dist, k = free[hit], dist[hit], k[hit]
    dz = points[free, 2] - z[k]
    inside = (
        (dist <= radius[k])
        & (np.nan_to_num(dz, nan=0.0) >= -below_m)
        & (np.nan_to_num(dz, nan=0.0) <= above_m)
    )
    ids[free[inside]] = np.asarray(trees["id"])[k[inside]]
    return ids


MAX_GRID_CELLS = 1 << 24  # the prefilter's grid (bytes); beyond, every point goes to the query


def _maybe_near(xy: np.ndarray, centres: np.ndarray, reach: float) -> np.ndarray:
    """(N,) False for points xy (N,2) certainly farther than `reach` from every centre (M,2),
    True for the others (which may be farther): a grid of `reach` cells over the centres, each
    marking the 5x5 cells around its own (a point within `reach` of a centre lies at most one
    cell away, two with rounding). A cKDTree query of every map point cost 3x this."""
    if not (reach > 0 and np.isfinite(centres).all()) or len(centres) == 0 or len(xy) == 0:
        return np.ones(len(xy), dtype=bool)
    lo = centres.min(axis=0) - 3 * reach
    shape = np.floor((centres.max(axis=0) + 3 * reach - lo) / reach).astype(np.int64) + 1
    if shape.prod() > MAX_GRID_CELLS:
        return np.ones(len(xy), dtype=bool)
    grid = np.zeros(shape, dtype=bool)
    cell = np.floor((centres - lo) / reach).astype(np.int64)
    for dx in range(-2, 3):
        for dy in range(-2, 3):
            grid[cell[:, 0] + dx, cell[:, 1] + dy] = True
    at = np.floor((xy - lo) / reach)
    inside = (at[:, 0] >= 0) & (at[:, 0] < shape[0]) & (at[:, 1] >= 0) & (at[:, 1] < shape[1])
    near = np.zeros(len(xy), dtype=bool)
    at = at[inside].astype(np.int64)
    near[inside] = grid[at[:, 0], at[:, 1]]
    return near
