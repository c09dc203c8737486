"""Merge two sessions' tree maps: B placed in A's frame by global localization plus refinement.

Placement (`align_tree_maps`): B's trees around points of B's trajectory (every `query_step_m`,
within `query_radius_m`) are localized in A's map by the Delaunay-star localizer, each query
judged by the localizer's own acceptance test. Accepted poses vote: the largest group agreeing
within `agree_m` / `agree_deg` wins, and it must hold at least `min_agreeing` queries, so one
lucky query cannot place a map. The pose is then refined on every tree pair (mutual nearest
neighbours within `gate_m`) by a planar rigid fit, repeated until the pairs stop changing.

Fusion (`fuse_trees`): a tree of both maps gets the observation-weighted mean position, the
inverse-variance DBH (dbh_std_m; equal weights where a spread is missing) and the summed
observation count; trees of one map only are kept as they are. `source` says which: a, b, both.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from forestslam.errors import InputError
from forestslam.geometry import planar_pose, rigid_fit, transform_points, transform_xy, yaw_of
from forestslam.localization import build_map, localize
from forestslam.localization.config import LocalizationConfig
from forestslam.multisession.fusion import fuse_dbh

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MergeConfig:
    query_step_m: float = 10.0
    query_radius_m: float = 15.0
    min_query_trees: int = 6
    agree_m: float = 0.5
    agree_deg: float = 2.0
    min_agreeing: int = 2
    gate_m: float = 0.5
    refine_iterations: int = 10
    dbh_sigma_m: float = 0.02  # a DBH without its own spread (dbh_std_m)
    # levelling on the matched trees' heights (forestslam.multisession.level)
    level_min_trees: int = 8
    level_max_tilt_deg: float = 15.0


@dataclass(frozen=True)
class MapAlignment:
    """T_a_b (4,4) planar pose of B's frame in A's; `pairs` (K,2) indices (A, B) of the trees
    matched by the refinement; `rms_m` of their residuals; `queries` / `accepted` / `agreeing`
    localization queries."""

    T_a_b: np.ndarray
    pairs: np.ndarray
    rms_m: float
    queries: int
    accepted: int
    agreeing: int
    votes: list[dict] = field(default_factory=list)
    tilt_deg: float = 0.0  # of B's frame against A's when levelled on tree heights

    def to_dict(self) -> dict:
        yaw = math.degrees(math.atan2(self.T_a_b[1, 0], self.T_a_b[0, 0]))
        return {
            "x": float(self.T_a_b[0, 3]),
            "y": float(self.T_a_b[1, 3]),
            "yaw_deg": yaw,
            "matched_trees": int(len(self.pairs)),
            "rms_m": float(self.rms_m),
            "queries": self.queries,
            "accepted_queries": self.accepted,
            "agreeing_queries": self.agreeing,
            "tilt_deg": float(self.tilt_deg),
        }


def _query_centres(b_path_xy: np.ndarray, b_xy: np.ndarray, step_m: float) -> np.ndarray:
    """Points along B's path every `step_m` (B's tree centroid when there is no path)."""
    if len(b_path_xy) < 2:
        return b_xy.mean(axis=0, keepdims=True)
    seg = np.linalg.norm(np.diff(b_path_xy, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    return np.column_stack(
        [np.interp(np.arange(0.0, s[-1] + 1e-9, step_m), s, b_path_xy[:, k]) for k in (0, 1)]
    )


def _vote(poses: list[tuple[float, float, float]], config: MergeConfig) -> list[int]:
    """Indices of the largest group of poses agreeing with one of them."""
    best: list[int] = []
    for x, y, yaw in poses:
        group = [
            j
            for j, (x2, y2, yaw2) in enumerate(poses)
            if math.hypot(x2 - x, y2 - y) <= config.agree_m
            and abs(math.remainder(yaw2 - yaw, math.tau)) <= math.radians(config.agree_deg)
        ]
        best = group if len(group) > len(best) else best
    return best


def _refine(a_xy, b_xy, T, config: MergeConfig) -> tuple[np.ndarray, np.ndarray, float]:
    tree_a = cKDTree(a_xy)
    pairs = np.zeros((0, 2), dtype=np.int64)
    for _ in range(config.refine_iterations):
        moved = transform_xy(T, b_xy)
        d_ab, ia = tree_a.query(moved, distance_upper_bound=config.gate_m)
        d_ba, ib = cKDTree(moved).query(a_xy, distance_upper_bound=config.gate_m)
        jb = np.flatnonzero(np.isfinite(d_ab))
        mutual = jb[ib[ia[jb]] == jb]
        new = np.column_stack([ia[mutual], mutual])
        if len(new) < 3:
            raise InputError(f"refinement kept {len(new)} tree pairs: the maps do not overlap")
        fit = rigid_fit(b_xy[new[:, 1]], a_xy[new[:, 0]])  # (3,3) planar
        T = planar_pose(fit[0, 2], fit[1, 2], float(yaw_of(fit)))
        if np.array_equal(new, pairs):
            break
        pairs = new
    moved = transform_xy(T, b_xy[pairs[:, 1]])
    rms = float(np.sqrt(np.mean(np.sum((moved - a_xy[pairs[:, 0]]) ** 2, axis=1))))
    return T, pairs, rms


def align_tree_maps(
    a_xy: np.ndarray,
    b_xy: np.ndarray,
    b_path_xy: np.ndarray | None = None,
    config: MergeConfig = MergeConfig(),
    localization: LocalizationConfig | None = None,
) -> MapAlignment:
    """Place B's trees (N,2) in the frame of A's trees (M,2); InputError when no placement
    holds (too few agreeing queries, or no overlap)."""
    a_xy, b_xy = np.asarray(a_xy, np.float64), np.asarray(b_xy, np.float64)
    if len(a_xy) < 3 or len(b_xy) < 3:
        raise InputError(f"merging needs 3 or more trees in each map ({len(a_xy)}, {len(b_xy)})")
    path = np.zeros((0, 2)) if b_path_xy is None else np.asarray(b_path_xy, np.float64)
    tree_map, tree_b = build_map(a_xy), cKDTree(b_xy)
    poses, votes, queries = [], [], 0
    for centre in _query_centres(path, b_xy, config.query_step_m):
        local = b_xy[tree_b.query_ball_point(centre, config.query_radius_m)]
        if len(local) < config.min_query_trees:
            continue
        queries += 1
        loc = localize(tree_map, local, localization)
        votes.append({"x": float(centre[0]), "y": float(centre[1]), **loc.to_dict()})
        if loc.accepted:
            poses.append((loc.x, loc.y, loc.yaw))
    group = _vote(poses, config)
    if len(group) < config.min_agreeing:
        raise InputError(
            f"B could not be placed in A: {len(poses)} of {queries} localization queries "
            f"accepted, at most {len(group)} agreeing (need {config.min_agreeing})"
        )
    x, y = np.mean([poses[j][:2] for j in group], axis=0)
    yaw = math.atan2(*np.sum([[math.sin(poses[j][2]), math.cos(poses[j][2])] for j in group], 0))
    T, pairs, rms = _refine(a_xy, b_xy, planar_pose(x, y, yaw), config)
    log.info(
        "B placed in A: %d of %d queries agree, %d tree pairs, rms %.3f m",
        len(group),
        queries,
        len(pairs),
        rms,
    )
    return MapAlignment(T, pairs, rms, queries, len(poses), len(group), votes)


def fuse_trees(
    a: dict, b: dict, alignment: MapAlignment, config: MergeConfig = MergeConfig()
) -> dict[str, np.ndarray]:
    """The merged tree table (see the module doc) in A's frame; ids renumbered from 1."""
    T = alignment.T_a_b
    n_a, n_b = len(a["x"]), len(b["x"])
    b_xyz = transform_points(T, np.column_stack([b["x"], b["y"], b.get("z", np.zeros(n_b))]))
    a_xyz = np.column_stack([a["x"], a["y"], a.get("z", np.zeros(n_a))])
    cols = {}
    for name, default in (("dbh_m", np.nan), ("dbh_std_m", np.nan), ("observations", 1)):
        cols[name] = (
            np.asarray(a.get(name, np.full(n_a, default)), np.float64),
            np.asarray(b.get(name, np.full(n_b, default)), np.float64),
        )
    ia, ib = alignment.pairs[:, 0], alignment.pairs[:, 1]
    obs_a, obs_b = cols["observations"][0][ia], cols["observations"][1][ib]
    w_a = obs_a / (obs_a + obs_b)
    xyz = w_a[:, None] * a_xyz[ia] + (1 - w_a[:, None]) * b_xyz[ib]
    dbh, std = fuse_dbh(
        cols["dbh_m"][0][ia],
        cols["dbh_std_m"][0][ia],
        cols["dbh_m"][1][ib],
        cols["dbh_std_m"][1][ib],
        config.dbh_sigma_m,
    )
    only_a = np.setdiff1d(np.arange(n_a), ia)
    only_b = np.setdiff1d(np.arange(n_b), ib)
    parts = [
        (xyz, dbh, std, obs_a + obs_b, "both"),
        (
            a_xyz[only_a],
            cols["dbh_m"][0][only_a],
            cols["dbh_std_m"][0][only_a],
            cols["observations"][0][only_a],
            "a",
        ),
        (
            b_xyz[only_b],
            cols["dbh_m"][1][only_b],
            cols["dbh_std_m"][1][only_b],
            cols["observations"][1][only_b],
            "b",
        ),
    ]
    pos = np.concatenate([p[0] for p in parts])
    return {
        "id": np.arange(1, len(pos) + 1),
        "x": pos[:, 0],
        "y": pos[:, 1],
        "z": pos[:, 2],
        "dbh_m": np.concatenate([p[1] for p in parts]),
        "dbh_std_m": np.concatenate([p[2] for p in parts]),
        "observations": np.concatenate([p[3] for p in parts]).astype(np.int64),
        "source": np.concatenate([np.full(len(p[0]), p[4]) for p in parts]),
    }
