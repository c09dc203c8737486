"""A run that starts in a prior tree map (`forestslam run --prior-map MAP`).

The SLAM runs in its odometry frame as always. Until it is *placed*, the run's own trees near the
machine are queried against the prior map every `place_every_keyframes` keyframes by the
Delaunay-star localizer (its acceptance test decides; a rejected query adds nothing). Once
placed (or at once with `--initial-pose`), the prior trees enter the graph as landmarks with
position priors of their own uncertainty: the run's trees that the localizer matched become the
prior trees, the others are inserted, so re-observing them fuses position, DBH and counts.
Outputs are then expressed in the prior map's frame by `T_map_odom`, refitted at the end from
the optimised prior trees onto their map positions, so the whole run is in one frame: never half
in the odometry frame and half in the map's. A run never placed stays in its own frame and says
so in run.yaml.

Large coordinates (UTM) are kept exact: the map is shifted by `origin` (a round number near its
centre) for the localizer and the graph, and the shift is added back in `T_map_odom`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np

from forestslam.config_utils import Positive, PositiveInt, Range
from forestslam.errors import InputError
from forestslam.geometry import (
    parse_yaw,
    planar_pose,
    rigid_fit,
    transform_points,
    transform_xy,
    yaw_of,
)
from forestslam.multisession.fusion import fuse_dbh
from forestslam.multisession.level import level_fit

log = logging.getLogger(__name__)


@dataclass
class PriorMapConfig:
    # Position sigma of a prior tree: from a field inventory (tape and compass, GNSS under
    # canopy), and from a forestslam map (a run directory or saved map).
    inventory_sigma_m: Positive = 0.3
    map_sigma_m: Positive = 0.05
    dbh_sigma_m: Positive = 0.01  # a DBH (prior's or run's) without its own spread (dbh_std_m)
    place_every_keyframes: PositiveInt = 4  # placement attempts while not placed
    place_radius_m: Positive = 25.0  # the run's trees around the machine that form a query
    place_min_trees: Annotated[int, Range(ge=3)] = 6
    # Levelling: each run's frame is its first scan's sensor frame, tilted by the slope and
    # sway where it started; a planar placement leaves the tilt between the run and the map, so
    # the trajectory and the trees sit apart by tilt x height difference (terrain relief). With
    # tree centre heights in both (a forestslam map), the final fit is a 3D rigid fit of the
    # re-observed trees when this many have heights and the tilt found is plausible.
    level_min_trees: Annotated[int, Range(ge=3)] = 8
    level_max_tilt_deg: Positive = 15.0


@dataclass(frozen=True)
class PriorMap:
    """Trees of a prior map in its local frame (map coordinates minus `origin`)."""

    xy: np.ndarray  # (M,2) local
    dbh_m: np.ndarray  # (M,) NaN where unknown
    dbh_std_m: np.ndarray  # (M,) NaN where unknown
    z: np.ndarray  # (M,) breast-height centre heights, NaN where unknown (an inventory)
    observations: np.ndarray  # (M,) observation counts (1 for an inventory)
    ids: np.ndarray  # (M,) the map's tree ids
    sigma_m: np.ndarray  # (M,) position sigma
    origin: np.ndarray  # (2,) map coordinates of the local origin
    source: str

    def __len__(self) -> int:
        return len(self.xy)


def _column(table: dict, names: tuple[str, ...], n: int, default: float) -> np.ndarray:
    for name in names:
        if name in table and np.asarray(table[name]).dtype.kind in "fiu":
            return np.asarray(table[name], dtype=np.float64)
    return np.full(n, default)


def load_prior_map(path: str | Path, config: PriorMapConfig | None = None) -> PriorMap:
    """A tree CSV (`x,y[,dbh_m|dbh_cm][,id|tree][,dbh_std_m][,observations]`, any frame, UTM
    included), a saved map (.npz) or an earlier run's directory (its trees.csv)."""
    from forestslam.io import read_trees_csv

    config = config or PriorMapConfig()
    path = Path(path)
    if path.is_dir():
        if not (path / "trees.csv").is_file():
            raise InputError(f"--prior-map {path}: a run directory needs its trees.csv")
        table, sigma, kind = read_trees_csv(path / "trees.csv"), config.map_sigma_m, "run"
    elif path.suffix.lower() == ".npz":
        from forestslam.localization import load_map

        saved = load_map(path)
        table = {"x": saved.xy[:, 0], "y": saved.xy[:, 1], "dbh_m": saved.dbh_m}
        sigma, kind = config.map_sigma_m, "saved map"
    elif path.is_file():
        table, sigma, kind = read_trees_csv(path), config.inventory_sigma_m, "tree table"
    else:
        raise InputError(f"--prior-map {path}: not found")
    if "x" not in table or "y" not in table:
        raise InputError(f"--prior-map {path}: needs x and y columns")
    xy = np.column_stack([table["x"], table["y"]]).astype(np.float64)
    keep = np.isfinite(xy).all(axis=1)
    if keep.sum() < 3:
        raise InputError(f"--prior-map {path}: fewer than 3 trees with coordinates")
    if not keep.all():
        log.warning("--prior-map %s: %d rows without finite x, y ignored", path, (~keep).sum())
    n = len(xy)
    dbh = _column(table, ("dbh_m",), n, np.nan)
    if "dbh_m" not in table and "dbh_cm" in table:
        dbh = _column(table, ("dbh_cm",), n, np.nan) / 100.0
    ids = _column(table, ("id", "tree"), n, np.nan)
    ids = np.where(np.isfinite(ids), ids, np.arange(1, n + 1)).astype(np.int64)
    origin = np.round(np.median(xy[keep], axis=0), -2)  # a round shift keeps UTM digits exact
    log.info("prior map %s: %d trees (%s), origin %s", path, keep.sum(), kind, origin.tolist())
    return PriorMap(
        xy=xy[keep] - origin,
        dbh_m=dbh[keep],
        dbh_std_m=_column(table, ("dbh_std_m",), n, np.nan)[keep],
        z=_column(table, ("z",), n, np.nan)[keep],
        observations=_column(table, ("observations",), n, 1.0)[keep],
        ids=ids[keep],
        sigma_m=_column(table, ("sigma_m", "position_std_m"), n, sigma)[keep],
        origin=origin,
        source=f"{kind} {path}",
    )


def parse_initial_pose(text: str) -> np.ndarray:
    """`x,y,yaw_deg` -> (3,) x, y (map coordinates) and yaw (radians; geometry.parse_yaw)."""
    *head, last = text.split(",")
    try:
        values = [float(v) for v in head] + [parse_yaw(last, "--initial-pose")]
    except ValueError:
        values = []
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise InputError(f"--initial-pose must be x,y,yaw_deg (three numbers), not {text!r}")
    return np.array(values)


class PriorTracker:
    """Places a run in a prior map and feeds the prior trees to its SLAM (see module doc)."""

    def __init__(self, prior: PriorMap, config: PriorMapConfig | None = None, localization=None):
        from forestslam.localization import build_map

        self.prior, self.cfg, self.localization = prior, config or PriorMapConfig(), localization
        self.index = build_map(prior.xy, prior.dbh_m)
        self.T_local_odom: np.ndarray | None = None  # prior-local frame <- odometry frame
        self.placement: dict = {"placed": False, "attempts": 0, "rejected": 0}
        self.prior_landmarks = np.full(len(prior), -1, dtype=np.int64)  # SLAM landmark ids

    @property
    def placed(self) -> bool:
        return self.T_local_odom is not None

    def place_at(self, slam, T_map_sensor0: np.ndarray, scan: int, stamp: float) -> None:
        """`--initial-pose`: the first scan's pose in map coordinates is given."""
        T = T_map_sensor0.copy()
        T[:2, 3] -= self.prior.origin
        self._placed(slam, T, {"method": "initial-pose"}, scan, stamp, matches={})

    def maybe_place(self, slam, keyframe: int, T_odom_sensor: np.ndarray, scan: int, stamp):
        """At a keyframe while not placed: query the prior map with the run's trees around the
        machine; a pose the localizer accepts places the run."""
        if self.placed or keyframe % self.cfg.place_every_keyframes:
            return
        from forestslam.localization import localize

        xy, _ = slam.landmarks()
        near = np.linalg.norm(xy - T_odom_sensor[:2, 3], axis=1) <= self.cfg.place_radius_m
        if near.sum() < self.cfg.place_min_trees:
            return
        self.placement["attempts"] += 1
        loc = localize(self.index, xy[near], self.localization)
        if loc.rejected:
            self.placement["rejected"] += 1
            log.debug("prior map: placement at scan %d rejected (%s)", scan, loc.reason)
            return
        lm_ids = np.flatnonzero(near)
        matches = {int(lm_ids[i]): int(j) for i, j in np.asarray(loc.matches).reshape(-1, 2)}
        info = {
            "method": "global localization",
            "inliers": int(loc.inliers),
            "second_inliers": int(loc.second_inliers),
            "query_trees": int(near.sum()),
        }
        self._placed(slam, loc.matrix(), info, scan, stamp, matches)

    def _placed(self, slam, T_local_odom, info, scan, stamp, matches: dict[int, int]) -> None:
        self.T_local_odom = T_local_odom
        T_odom_local = np.linalg.inv(T_local_odom)
        xy_odom = transform_xy(T_odom_local, self.prior.xy)
        self.prior_landmarks = slam.add_prior_landmarks(
            xy_odom, self.prior.dbh_m, self.prior.observations, self.prior.sigma_m, matches
        )
        self.placement.update(
            info, placed=True, scan=int(scan), stamp=float(stamp), matched_trees=len(matches)
        )
        log.info(
            "placed in the prior map at scan %d (%s, %d trees matched)",
            scan,
            info["method"],
            len(matches),
        )

    def refit(self, slam) -> None:
        """T_local_odom refitted from the prior trees this run saw again: their optimised
        positions onto their map positions. The observations outweigh an inventory's priors,
        so this removes what the placement got wrong. Planar, or 3D (levelled, see
        PriorMapConfig.level_*) when the map and the run have the trees' heights."""
        if not self.placed:
            return
        xy, _ = slam.landmarks()
        mine = np.flatnonzero(self.prior_landmarks >= 0)
        mine = mine[slam.observed_this_run()[self.prior_landmarks[mine]]]
        if len(mine) < 3:
            return
        lm = self.prior_landmarks[mine]
        fit = rigid_fit(xy[lm], self.prior.xy[mine])  # (3,3) planar
        self.T_local_odom = planar_pose(fit[0, 2], fit[1, 2], float(yaw_of(fit)))
        levelled = level_fit(
            np.column_stack([xy[lm], slam.landmark_heights()[lm]]),
            np.column_stack([self.prior.xy[mine], self.prior.z[mine]]),
            self.cfg.level_min_trees,
            self.cfg.level_max_tilt_deg,
        )
        if levelled is not None:
            self.T_local_odom = levelled[0]
            self.placement.update(tilt_deg=levelled[1], levelled_trees=levelled[2])

    def T_map_odom(self) -> np.ndarray:
        """Map coordinates <- odometry frame (identity while not placed)."""
        if not self.placed:
            return np.eye(4)
        T = self.T_local_odom.copy()
        T[:2, 3] += self.prior.origin
        return T

    def tree_status(self, n_landmarks: int, observed_this_run: np.ndarray) -> np.ndarray:
        """Per SLAM landmark: `new`, `updated` (a prior tree seen again) or `kept`."""
        status = np.full(n_landmarks, "new", dtype=object)
        prior = self.prior_landmarks[self.prior_landmarks >= 0]
        status[prior] = np.where(observed_this_run[prior], "updated", "kept")
        return status

    # ------------------------------------------------------------------ outputs in the map frame
    def table_counts(self, observations: np.ndarray) -> np.ndarray:
        """Counts that make the tree table keep every prior tree, seen again or not."""
        counts = np.asarray(observations).copy()
        prior = self.prior_landmarks[self.prior_landmarks >= 0]
        counts[prior] = np.iinfo(np.int64).max
        return counts

    def express_table(self, table: dict, slam) -> dict:
        """The run's tree table (landmark ids, odometry frame) in the prior map: map ids (new
        trees numbered after the map's), fused DBH, summed counts, `status` new / updated /
        kept, x, y in map coordinates."""
        lm = np.asarray(table["id"], dtype=np.int64)
        _, nobs = slam.landmarks()
        prior_of = np.full(slam.n_landmarks, -1, dtype=np.int64)
        mine = self.prior_landmarks >= 0
        prior_of[self.prior_landmarks[mine]] = np.flatnonzero(mine)
        j = prior_of[lm]
        is_prior = j >= 0
        p = self.prior
        dbh, std = fuse_dbh(
            table["dbh_m"],
            table["dbh_std_m"],
            np.where(is_prior, p.dbh_m[j], np.nan),
            np.where(is_prior, p.dbh_std_m[j], np.nan),
            self.cfg.dbh_sigma_m,
        )
        first_new = int(p.ids.max()) + 1 if len(p.ids) else 1
        ids = np.where(is_prior, p.ids[j], first_new + np.cumsum(~is_prior) - 1)
        status = self.tree_status(slam.n_landmarks, slam.observed_this_run())[lm]
        T = self.T_map_odom()
        z = np.asarray(table.get("z", np.full(len(lm), np.nan)), dtype=np.float64)
        z_fill = np.where(np.isfinite(z), z, np.nanmean(z) if np.isfinite(z).any() else 0.0)
        xyz = transform_points(T, np.column_stack([table["x"], table["y"], z_fill]))
        out = dict(table)
        out.update(
            id=ids,
            x=xyz[:, 0],
            y=xyz[:, 1],
            dbh_m=dbh,
            dbh_std_m=std,
            observations=nobs[lm].astype(np.int64),
            status=status,
        )
        if "z" in table:
            out["z"] = np.where(np.isfinite(z), xyz[:, 2], np.nan)
        return out

    def express_poses(self, poses: np.ndarray) -> np.ndarray:
        """Poses (N,4,4) of the odometry frame in map coordinates."""
        return np.einsum("ij,njk->nik", self.T_map_odom(), np.asarray(poses, np.float64))

    def to_dict(self) -> dict:
        """What run.yaml says of the prior map and the placement."""
        T = self.T_map_odom()
        placement = dict(self.placement)
        if self.placed:
            placement["T_map_odom"] = {
                "x": float(T[0, 3]),
                "y": float(T[1, 3]),
                "yaw_deg": math.degrees(math.atan2(T[1, 0], T[0, 0])),
            }
            placement["frame"] = "prior map"
        else:
            placement["frame"] = "own (the first scan's sensor frame): never placed in the map"
        return {"source": self.prior.source, "trees": len(self.prior), "placement": placement}
