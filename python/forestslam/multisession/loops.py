"""Loop closure and relocalization by place recognition, inside one run.

Re-association under the odometry's prediction re-finds trees only while the pose error is within
its search radius: past that (a long excursion's drift) the SLAM maps the same trees a second
time. The symptom is checked every `every_keyframes` keyframes: near the machine there are trees
mapped earlier that the SLAM has not re-found lately, and trees it has just mapped. Then the
newly mapped trees are localized by the Delaunay-star localizer among all trees mapped earlier
(and prior-map trees); when its acceptance test holds and the place disagrees with the graph by
more than `min_correction_m`, each matched pair (older copy, newer copy) is tied by a factor
(`LandmarkSlam.tie_trees`). A rejected query adds nothing, and a correction beyond
`max_correction_m` is refused.

Revisit: when the SLAM's consensus moved a keyframe's scan onto older copies of the trees it was
tracking, the SLAM declines the move and keeps its chain (`LandmarkSlam.pending_revisit`); at
that keyframe the trees it tracks are localized among the trees not re-found lately, and an
accepted place ties them as above: the loop closes without a tracking loss.

Relocalization: when the SLAM lost track (the trees it tracked vanished at once: an odometry
jump), it starts a segment nearly free of the odometry chain (`LandmarkSlam.lost_since`). At
every keyframe the segment's own trees are then localized among the trees mapped before it,
anywhere in the map; the first accepted place ties them (the segment moves onto the map, however
far) and tracking resumes against every tree.

The Delaunay index of the mapped trees is kept between queries and rebuilt only when trees moved
(a closure) or the mapped set grew by `rebuild_growth` (building costs ~100x a query).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from forestslam.config_utils import NonNegative, Positive, PositiveInt, Range

log = logging.getLogger(__name__)


@dataclass
class PlaceRecognitionConfig:
    enabled: bool = True
    every_keyframes: PositiveInt = 5
    window_keyframes: PositiveInt = 12  # "just mapped" / "re-found lately": within this many
    radius_m: Positive = 20.0
    min_query_trees: Annotated[int, Range(ge=3)] = 6
    min_correction_m: Positive = 0.3
    max_correction_m: Positive = 50.0
    tie_sigma_m: Positive = 0.1
    # the kept Delaunay index is rebuilt when a tree moved this much or the set grew by this
    rebuild_growth: NonNegative = 0.1
    index_tolerance_m: Positive = 0.1


class PlaceRecognition:
    def __init__(self, config: PlaceRecognitionConfig | None = None, localization=None) -> None:
        self.cfg = config or PlaceRecognitionConfig()
        self.localization = localization
        self.stats = {
            "queries": 0,
            "rejected": 0,
            "consistent": 0,
            "refused": 0,
            "closures": 0,
            "relocalization_queries": 0,
            "relocalizations": 0,
            "revisit_queries": 0,
            "revisit_closures": 0,
            "index_builds": 0,
        }
        self._index = None  # (TreeMap, landmark ids, their positions when built)
        self.reasons: dict[str, int] = {}  # why loop queries were rejected: count per reason

    def step(self, slam, keyframe: int, T_map_sensor: np.ndarray) -> bool:
        """At a keyframe: relocalize a lost segment, or query for a loop and, when one is
        verified, tie the trees. True when trees were tied."""
        if not self.cfg.enabled:
            return False
        if slam.lost_since is not None:
            return self._relocalize(slam, keyframe, T_map_sensor)
        if slam.pending_revisit == keyframe:
            return self._verify_revisit(slam, keyframe, T_map_sensor)
        return self._close_loop(slam, keyframe, T_map_sensor)

    def _close_loop(self, slam, keyframe: int, T_map_sensor: np.ndarray) -> bool:
        c = self.cfg
        if keyframe % c.every_keyframes or keyframe < c.window_keyframes:
            return False
        xy, first, last, alive, near, lately = self._landmarks_around(slam, keyframe, T_map_sensor)
        recent = alive & near & (first >= lately)  # just mapped: second copies, or new trees
        old = alive & (first < lately)  # mapped earlier (prior-map trees never seen: -1)
        lost = old & near & (last < lately)  # mapped earlier, here, and not re-found lately
        asked = self._ask(xy, recent, old, lost, "queries")
        if asked is None:
            return False
        loc, m_ids, q_ids = asked
        if loc.rejected:
            log.debug(
                "place recognition: query at keyframe %d (%d trees among %d) rejected: %s",
                keyframe,
                len(q_ids),
                int(old.sum()),
                loc.reason,
            )
            return False
        return self._tie_verified(slam, loc, m_ids, q_ids, keyframe, "loop closed")

    def _verify_revisit(self, slam, keyframe: int, T_map_sensor: np.ndarray) -> bool:
        """The SLAM declined a consensus move onto older copies of its tracked trees at this
        keyframe (`LandmarkSlam.pending_revisit`): the trees it tracks here are localized among
        the trees not re-found lately (where the older copies are); an accepted place ties
        them, which closes the loop through the unbroken chain. Rejected: nothing is added and
        the SLAM keeps tracking the recent copies."""
        xy, _, last, alive, near, lately = self._landmarks_around(slam, keyframe, T_map_sensor)
        tracked = alive & near & (last >= lately)  # the recent copies, and trees seen first now
        mapped = alive & (last < lately)  # not re-found lately: the older copies among them
        asked = self._ask(xy, tracked, mapped, mapped & near, "revisit_queries")
        if asked is None or asked[0].rejected:
            return False
        loc, m_ids, q_ids = asked
        tied = self._tie_verified(slam, loc, m_ids, q_ids, keyframe, "revisit verified")
        self.stats["revisit_closures"] += int(tied)
        return tied

    def _landmarks_around(self, slam, keyframe: int, T_map_sensor: np.ndarray):
        """The SLAM's landmark positions, the keyframes each was first and last seen at, which
        are alive (not merged into another) and within radius_m of the sensor, and the first
        keyframe of the recent window."""
        xy, _ = slam.landmarks()
        first, last = slam.landmark_keyframes()
        alive = slam.aliases() < 0
        near = np.linalg.norm(xy - T_map_sensor[:2, 3], axis=1) <= self.cfg.radius_m
        return xy, first, last, alive, near, keyframe - self.cfg.window_keyframes

    def _ask(self, xy, query, among, among_here, counter: str):
        """Localize the `query` trees among the `among` ones, when each side has min_query_trees
        (`among_here`: those of `among` around the sensor), counting the query under `counter`
        and a rejection with its reason (run.yaml). None when too few to ask, else the
        localization, the map and query landmark ids."""
        if min(query.sum(), among_here.sum()) < self.cfg.min_query_trees:
            return None
        self.stats[counter] += 1
        q_ids = np.flatnonzero(query)
        loc, m_ids = self._query(xy, among, xy[q_ids])
        if loc.rejected:
            self.stats["rejected"] += 1
            self.reasons[loc.reason] = self.reasons.get(loc.reason, 0) + 1
        return loc, m_ids, q_ids

    def _tie_verified(self, slam, loc, m_ids, q_ids, keyframe: int, what: str) -> bool:
        """Tie the trees of an accepted place unless it agrees with the graph already or its
        correction is beyond `max_correction_m`; True when tied (a loop closure)."""
        c = self.cfg
        shift = math.hypot(loc.x, loc.y)  # the query is in the graph's frame: identity = agree
        if shift < c.min_correction_m and abs(loc.yaw) < math.radians(2.0):
            self.stats["consistent"] += 1
            return False
        if shift > c.max_correction_m:
            self.stats["refused"] += 1
            log.warning(
                "place recognition: a %.1f m correction refused at keyframe %d", shift, keyframe
            )
            return False
        slam.tie_trees(self._pairs(loc, m_ids, q_ids), c.tie_sigma_m)
        self.stats["closures"] += 1
        log.info(
            "place recognition: %s at keyframe %d (%d trees, %.2f m, %.2f deg)",
            what,
            keyframe,
            len(loc.matches),
            shift,
            math.degrees(loc.yaw),
        )
        return True

    def _relocalize(self, slam, keyframe: int, T_map_sensor: np.ndarray) -> bool:
        """The lost segment's trees around the machine localized among the trees mapped before
        the loss (anywhere: a lost pose bounds nothing); accepted -> tied, tracking resumes."""
        c = self.cfg
        xy, _ = slam.landmarks()
        first, _ = slam.landmark_keyframes()
        alive = slam.aliases() < 0
        near = np.linalg.norm(xy - T_map_sensor[:2, 3], axis=1) <= c.radius_m
        segment = alive & near & (first >= slam.lost_since)
        mapped = alive & (first < slam.lost_since)
        if segment.sum() < c.min_query_trees or mapped.sum() < c.min_query_trees:
            return False
        self.stats["relocalization_queries"] += 1
        q_ids = np.flatnonzero(segment)
        loc, m_ids = self._query(xy, mapped, xy[q_ids])
        if loc.rejected:
            return False
        pairs, lost_since = self._pairs(loc, m_ids, q_ids), slam.lost_since
        slam.relocalized(pairs, c.tie_sigma_m)
        self.stats["relocalizations"] += 1
        log.info(
            "place recognition: relocalized at keyframe %d (lost since %d, %d trees, %.2f m, "
            "%.2f deg)",
            keyframe,
            lost_since,
            len(pairs),
            math.hypot(loc.x, loc.y),
            math.degrees(loc.yaw),
        )
        return True

    def _query(self, xy: np.ndarray, mapped: np.ndarray, query_xy: np.ndarray):
        """Localize query_xy (K,2) among the trees `mapped` (L,) bool; (result, ids the result's
        map indices refer to)."""
        from forestslam.localization import build_map, localize

        ids = np.flatnonzero(mapped)
        if not self._index_fits(xy, ids):
            self._index = (build_map(xy[ids]), ids, xy[ids].copy())
            self.stats["index_builds"] += 1
        tree_map, m_ids, _ = self._index
        return localize(tree_map, query_xy, self.localization), m_ids

    def _index_fits(self, xy: np.ndarray, ids: np.ndarray) -> bool:
        """Whether the kept index still stands for the trees `ids`: all of its trees are among
        them, none moved by more than `index_tolerance_m`, and few new ones are missing."""
        if self._index is None:
            return False
        _, m_ids, m_xy = self._index
        c = self.cfg
        if len(ids) > len(m_ids) * (1.0 + c.rebuild_growth) or not np.isin(m_ids, ids).all():
            return False
        return float(np.abs(xy[m_ids] - m_xy).max(initial=0.0)) <= c.index_tolerance_m

    @staticmethod
    def _pairs(loc, m_ids: np.ndarray, q_ids: np.ndarray) -> np.ndarray:
        """(K,2) landmark indices (map tree, query tree) of the localizer's matches."""
        m = np.asarray(loc.matches, dtype=np.int64).reshape(-1, 2)
        return np.column_stack([m_ids[m[:, 1]], q_ids[m[:, 0]]])
