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

Local closure: at every keyframe, the trees just mapped around the machine are matched to the
trees mapped earlier and not re-found lately by the association's consensus (one rigid shift
within the SLAM's search radius); when that many agreeing trees are improbable by chance at the
local tree density (binomial tail, paid for every shift tried), the pairs are tied. It closes
the loops whose error the pose uncertainty bounds, which the global query, searching the whole
map, cannot tell from chance.

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
    # Local closure (see `_close_locally`): the trees just mapped and the trees not re-found
    # lately around the machine, matched under one rigid shift within the SLAM's search radius;
    # tied when the support is this improbable by chance (-log10): 5, once in 10^5 queries,
    # against a few hundred (the keyframes where both sets have min_query_trees) per 4.5 km.
    local_consensus: bool = True
    local_min_significance: NonNegative = 5.0


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
            "local_closures": 0,
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
        if keyframe < c.window_keyframes:
            return False
        xy, first, last, alive, near, lately = self._landmarks_around(slam, keyframe, T_map_sensor)
        recent = alive & near & (first >= lately)  # just mapped: second copies, or new trees
        old = alive & (first < lately)  # mapped earlier (prior-map trees never seen: -1)
        lost = old & near & (last < lately)  # mapped earlier, here, and not re-found lately
        if self._close_locally(slam, keyframe, xy, recent, lost):
            return True
        if keyframe % c.every_keyframes:
            return False
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

    def _close_locally(self, slam, keyframe: int, xy, recent, lost) -> bool:
        """A loop the SLAM's own pose uncertainty bounds: back at a place after a long
        excursion, the association keeps the trees it tracks and maps the place's trees a
        second time when they lie beyond its gate (Wild-Places V03: 25 trees mapped twice
        1.0-1.5 m apart, a bend the global query could not verify against 7,000 trees). The
        just-mapped trees are matched to the ones not re-found lately by one rigid shift within
        the SLAM's search radius (`shared_shift`); the pairs are tied when that many agreeing
        trees are improbable by chance at the local density, paid for every shift tried
        (`chance_significance`). Never two trees one keyframe saw (a recent tree was first seen
        after every lost tree's last sighting), never one pair alone."""
        from scipy.spatial import cKDTree

        from forestslam.slam.association import shared_shift

        c = self.cfg
        if not c.local_consensus or min(recent.sum(), lost.sum()) < c.min_query_trees:
            return False
        m_ids = np.flatnonzero(lost)
        radius = slam.search_radius()
        # only recent trees some shift within the radius could put on a lost one count
        reach = cKDTree(xy[m_ids]).query(xy[recent])[0] <= radius + slam.cfg.consensus_inlier_m
        q_ids = np.flatnonzero(recent)[reach]
        if len(q_ids) < c.min_query_trees:
            return False
        _, pairs, tried = shared_shift(xy[q_ids], xy[m_ids], radius, slam.cfg)
        if len(pairs) < c.min_query_trees:
            return False
        density = local_density(xy[m_ids], c.radius_m)
        inlier_m = slam.cfg.consensus_inlier_m
        sig = chance_significance(len(pairs), len(q_ids), tried, density, inlier_m)
        if sig < c.local_min_significance:
            log.debug(
                "local closure at keyframe %d: %d of %d trees agree, significance %.1f: too low",
                keyframe,
                len(pairs),
                len(q_ids),
                sig,
            )
            return False
        tied = np.column_stack([m_ids[pairs[:, 1]], q_ids[pairs[:, 0]]])
        apart = float(np.median(np.linalg.norm(xy[tied[:, 0]] - xy[tied[:, 1]], axis=1)))
        slam.tie_trees(tied, c.tie_sigma_m)
        self.stats["local_closures"] += 1
        log.info(
            "place recognition: local closure at keyframe %d (%d of %d trees, %.2f m apart, "
            "significance %.1f)",
            keyframe,
            len(pairs),
            len(q_ids),
            apart,
            sig,
        )
        return True

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


def local_density(xy: np.ndarray, radius_m: float) -> float:
    """Trees per m^2 of the points xy (N,2) around the machine: the larger of their count over
    the query disc and the density their mean nearest-neighbour distance gives (a Poisson
    pattern of density rho has mean 0.5 / sqrt(rho)), so a clump is not taken for a sparse
    stand."""
    from scipy.spatial import cKDTree

    disc = len(xy) / (math.pi * radius_m**2)
    if len(xy) < 2:
        return disc
    nn = cKDTree(xy).query(xy, k=2)[0][:, 1]
    return max(disc, 0.25 / max(float(np.mean(nn)) ** 2, 1e-6))


def chance_significance(
    support: int, n_query: int, hypotheses: int, density: float, inlier_m: float
) -> float:
    """-log10 of the chance that one of `hypotheses` shifts puts `support` of `n_query` trees
    within `inlier_m` of a mapped tree at `density` (trees per m^2). A shift is seeded by one
    pair, which it aligns for free; each other tree lands near a mapped one independently with
    p = 1 - exp(-density pi inlier_m^2): binomial tail of support - 1 among n_query - 1,
    Bonferroni over the shifts."""
    from scipy.stats import binom

    if support < 2 or n_query < 2:
        return 0.0
    p = 1.0 - math.exp(-density * math.pi * inlier_m**2)
    log_tail = float(binom.logsf(support - 2, n_query - 1, p)) / math.log(10.0)
    return -(math.log10(max(hypotheses, 1)) + log_tail)
