"""Loop closure and relocalization by place recognition, inside one run.

Re-association under the odometry's prediction re-finds trees only while the pose error is within
its search radius: past that (a long excursion's drift, or a loss: a jump of the odometry, a gap
in the recording) the SLAM maps the same trees a second time. The symptom is checked every
`every_keyframes` keyframes: near the machine there are trees mapped earlier that the SLAM has
not re-found lately, and trees it has just mapped. Then the newly mapped trees are localized by
the Delaunay-star localizer among all trees mapped earlier (and prior-map trees); when its
acceptance test holds and the place disagrees with the graph by more than `min_correction_m`,
each matched pair (older copy, newer copy) is tied by a robust factor. A rejected query adds
nothing, and a correction beyond `max_correction_m` is refused.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from forestslam.config_utils import Positive, PositiveInt, Range

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


class PlaceRecognition:
    def __init__(self, config: PlaceRecognitionConfig | None = None, localization=None) -> None:
        self.cfg = config or PlaceRecognitionConfig()
        self.localization = localization
        self.stats = {"queries": 0, "rejected": 0, "consistent": 0, "refused": 0, "closures": 0}

    def step(self, slam, keyframe: int, T_map_sensor: np.ndarray) -> bool:
        """At a keyframe: query and, when a loop is verified, tie the trees. True on a closure."""
        c = self.cfg
        if not c.enabled or keyframe % c.every_keyframes or keyframe < c.window_keyframes:
            return False
        from forestslam.localization import build_map, localize

        xy, _ = slam.landmarks()
        first, last = slam.landmark_keyframes()
        alive = slam.aliases() < 0
        near = np.linalg.norm(xy - T_map_sensor[:2, 3], axis=1) <= c.radius_m
        lately = keyframe - c.window_keyframes
        recent = alive & near & (first >= lately)  # just mapped: second copies, or new trees
        old = alive & (first < lately)  # mapped earlier (prior-map trees never seen: -1)
        lost = old & near & (last < lately)  # mapped earlier, here, and not re-found lately
        if recent.sum() < c.min_query_trees or lost.sum() < c.min_query_trees:
            return False
        self.stats["queries"] += 1
        q_ids, m_ids = np.flatnonzero(recent), np.flatnonzero(old)
        loc = localize(build_map(xy[m_ids]), xy[q_ids], self.localization)
        if loc.rejected:
            self.stats["rejected"] += 1
            return False
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
        m = np.asarray(loc.matches, dtype=np.int64).reshape(-1, 2)
        pairs = np.column_stack([m_ids[m[:, 1]], q_ids[m[:, 0]]])
        slam.tie_trees(pairs, c.tie_sigma_m)
        self.stats["closures"] += 1
        log.info(
            "place recognition: loop closed at keyframe %d (%d trees, %.2f m, %.2f deg)",
            keyframe,
            len(pairs),
            shift,
            math.degrees(loc.yaw),
        )
        return True
