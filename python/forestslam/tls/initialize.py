"""Placing an MLS walk in the TLS frame without an initial pose (issue 17).

The frames before the first placement are chained by 3D-NDT frame to frame (odometry in a
local frame) and their stems (ring circle fits) are merged into a local stem map expressed in
the latest frame. Each time the local map holds enough stems, coarse hypotheses come from
stem-constellation matching against the reference's stems: the Delaunay triangle-star global
localizer (forestslam.localization) and the pairwise-spacing vote (tls.features), the best few
of each. Every hypothesis is refined on matched stems and verified by the stem-centre LM of
the latest frame against the reference (trusted: converged, not degenerate, residuals) and by
stem consensus (local stems on reference stems of similar radius, 10 cm gate after the LM). The
placement is the best verified hypothesis when no distinct one is nearly as good; otherwise
the walk goes on and the next frames are tried. Frames before the placed one get their pose by
chaining back through the odometry from it, each refined by the LM when that is trusted; they
are never merged into the map.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from forestslam.geometry import planar_pose, rigid_fit, rot_z, transform_xy, yaw_of
from forestslam.localization import LocalizationConfig, build_map, localize, merge_close
from forestslam.tls.config import TlsConfig
from forestslam.tls.features import (
    FrameFeatures,
    coarse_stem_hypotheses,
    ground_height_near,
)

if TYPE_CHECKING:
    from forestslam._core import StemCentreLmResult

log = logging.getLogger(__name__)


@dataclass
class PendingFrame:
    """A frame seen before the walk was placed: its features, its pose in the local odometry
    frame (T_local_sensor at mid-sweep) and what a record needs."""

    index: int
    stamp: float
    t_mid_s: float
    feats: FrameFeatures
    z_points: np.ndarray  # a subsample (<= 500, 3) of its points: height band of the LM target
    T_local: np.ndarray
    ground_z: float | None  # local ground height below the sensor (features.ground_height_near)
    ms: dict  # CPU time spent on it (features, ndt, target, lm)
    segment: int = 0  # odometry segment (a failed NDT starts a new one)


@dataclass
class Placement:
    """The latest frame's verified pose T_tls_sensor and what verified it."""

    T_tls_sensor: np.ndarray
    lm: StemCentreLmResult
    consensus: int
    local_stems: int
    hypotheses: int
    second_consensus: int
    source: str


@dataclass
class Attempt:
    """The best outcome of a placement attempt (for the error message when none succeeds)."""

    local_stems: int = 0
    best_consensus: int = 0
    second_consensus: int = 0
    reason: str = "no attempt (too few stems seen)"


@dataclass
class Initializer:
    """Collects frames until the walk can be placed on the reference's stems.
    lm_at(T_start, feats, z_points, ms) -> LM result against the map target."""

    ref_xy: np.ndarray
    ref_r: np.ndarray
    ref_points: np.ndarray
    config: TlsConfig
    pending: list[PendingFrame] = field(default_factory=list)
    segment: int = 0
    best: Attempt = field(default_factory=Attempt)
    attempts: int = 0

    def __post_init__(self):
        self.tree = cKDTree(self.ref_xy) if len(self.ref_xy) else None
        self.tree_map = build_map(self.ref_xy) if len(self.ref_xy) >= 3 else None
        self.hull = None
        if len(self.ref_xy) >= 3:
            try:
                self.hull = Delaunay(self.ref_xy)
            except QhullError:  # collinear stems
                self.hull = None

    def push(
        self, frame: PendingFrame, ndt_ok: bool, lm_at: Callable[..., StemCentreLmResult]
    ) -> Placement | None:
        """Add a frame (its odometry pose, ndt_ok False: odometry broke before it); try to
        place the latest frame when the local map allows it."""
        init = self.config.init
        if not ndt_ok:
            self.segment += 1
        frame.segment = self.segment
        window = [f for f in self.pending if f.segment == self.segment][-init.window_frames :]
        if window:
            frame.T_local = self.align(frame, window)
        self.pending.append(frame)
        window = window[-init.window_frames + 1 :] + [frame]
        if len(window) < init.min_frames:
            return None
        xy, r = self.local_stems(window)
        if len(xy) < init.min_local_stems or self.tree is None:
            return None
        self.attempts += 1
        return self.place(window[-1], xy, r, lm_at)

    def align(self, frame: PendingFrame, window: list[PendingFrame]) -> np.ndarray:
        """The frame's odometry pose (NDT) corrected in x, y and yaw by matching its stems to
        the stems of the window (local frame): NDT alone drifts or stalls where the scene has
        little structure, and a local stem map blurred by decimetres matches nothing. When
        the stems do not match from the NDT pose, the pairwise-spacing vote nearest to it
        (within 3 m and 30 deg) is refined instead."""
        xy, r = self.local_stems(window, np.eye(4), min_seen=1)
        src, src_r = frame.feats.stems[:, :2], frame.feats.stem_radii
        if len(xy) < 3 or len(src) < 3:
            return frame.T_local
        tree = cKDTree(xy)
        T = _refine_on(tree, xy, src, frame.T_local)
        if T is not None:
            return T
        guess = frame.T_local
        best, best_d = None, np.inf
        for (x, y, yaw), _ in coarse_stem_hypotheses(
            src, src_r, xy, r, self.config.registration, 3, 25
        ):
            T0 = _with_planar(guess, x, y, yaw)
            d = np.linalg.norm(T0[:2, 3] - guess[:2, 3])
            dyaw = abs(np.arctan2(*(np.linalg.inv(guess) @ T0)[[1, 0], 0]))
            if d < 3.0 and dyaw < np.radians(30.0) and d < best_d:
                best, best_d = T0, d
        if best is None:
            return guess
        T = _refine_on(tree, xy, src, best)
        return guess if T is None else T

    def local_stems(
        self, window: list[PendingFrame], T_to=None, min_seen: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Stems (K,2) and radii (K,) of the window's frames, merged, in the latest frame (or
        moved by T_to (4,4) from the local frame)."""
        T_last_inv = np.linalg.inv(window[-1].T_local) if T_to is None else T_to
        parts, radii, frame_ids = [], [], []
        for k, f in enumerate(window):
            if len(f.feats.stems) == 0:
                continue
            T = T_last_inv @ f.T_local
            parts.append(transform_xy(T, f.feats.stems[:, :2]))
            radii.append(f.feats.stem_radii)
            frame_ids.append(np.full(len(f.feats.stems), k))
        if not parts:
            return np.zeros((0, 2)), np.zeros(0)
        xy, r, ids = np.concatenate(parts), np.concatenate(radii), np.concatenate(frame_ids)
        centres, labels = merge_close(xy, self.config.init.merge_radius_m, return_labels=True)
        count = np.bincount(labels)
        r_mean = np.bincount(labels, weights=r) / count
        # A stem seen in one frame of many is more likely a false fit (a shrub, a branch).
        seen = np.zeros((len(centres), len(window)), dtype=bool)
        seen[labels, ids] = True
        if min_seen is None:
            min_seen = 2 if len(window) >= 3 else 1
        keep = seen.sum(axis=1) >= min_seen
        return centres[keep], r_mean[keep]

    def hypotheses(self, xy: np.ndarray, r: np.ndarray) -> list[tuple[np.ndarray, str]]:
        """Planar poses (x, y, yaw) of the local frame in the TLS frame, with their source."""
        init = self.config.init
        out = [
            (pose, "pairs")
            for pose, _ in coarse_stem_hypotheses(
                xy, r, self.ref_xy, self.ref_r, self.config.registration, init.hypotheses, 25
            )
        ]
        if self.tree_map is not None and len(xy) >= 3:
            loc = localize(self.tree_map, xy, LocalizationConfig(min_inliers=3))
            if loc.inliers >= self.config.registration.coarse_min_stems:
                out.insert(0, (np.array([loc.x, loc.y, loc.yaw]), "triangle-stars"))
        return out

    def refine(self, pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Planar pose refined on the local stems matched to reference stems, gate shrinking."""
        for gate in (0.5, 0.3, 0.15):
            T = planar_pose(*pose)
            moved = transform_xy(T, xy)
            d, j = self.tree.query(moved)
            ok = d < gate
            if ok.sum() < 3:
                break
            fit = rigid_fit(xy[ok], self.ref_xy[j[ok]])
            pose = np.array([fit[0, 2], fit[1, 2], yaw_of(fit)])
        return pose

    def consensus(self, T: np.ndarray, xy: np.ndarray, r: np.ndarray) -> tuple[int, int]:
        """Local stems moved by T that lie on a reference stem of similar radius, and how many
        of them lie inside the hull of the reference's stems (where the reference would have
        seen a stem; outside it no match is expected)."""
        init = self.config.init
        moved = transform_xy(T, xy)
        d, j = self.tree.query(moved)
        hit = (d < init.consensus_gate_m) & (np.abs(r - self.ref_r[j]) < init.consensus_radius_m)
        inside = self.hull.find_simplex(moved) >= 0 if self.hull is not None else hit
        return int(hit.sum()), int(np.sum(inside | hit))

    def place(self, latest: PendingFrame, xy, r, lm_at) -> Placement | None:
        from forestslam.tls.pipeline import trust_failure

        init = self.config.init
        verified: list[tuple[int, float, np.ndarray, StemCentreLmResult, str]] = []
        hyps = self.hypotheses(xy, r)
        for pose, source in hyps:
            pose = self.refine(pose, xy)
            T0 = planar_pose(*pose)
            g_ref = ground_height_near(self.ref_points, pose[:2])
            if g_ref is not None and latest.ground_z is not None:
                T0[2, 3] = g_ref - latest.ground_z
            lm = lm_at(T0, latest.feats, latest.z_points, latest.ms)
            if trust_failure(lm, None, self.config):
                continue
            T = np.asarray(lm.T_target_source)
            n, n_inside = self.consensus(T, xy, r)
            if any(_near(T, v[3]) for v in verified):
                continue
            verified.append((n, -float(lm.virtual_rms_m), n_inside, T, lm, source))
        verified.sort(key=lambda v: (v[0], v[1]), reverse=True)
        best_n = verified[0][0] if verified else 0
        second_n = verified[1][0] if len(verified) > 1 else 0
        inside = verified[0][2] if verified else len(xy)
        need = max(init.min_consensus_stems, int(np.ceil(init.min_consensus_fraction * inside)))
        reason = ""
        if not verified:
            reason = f"no hypothesis of {len(hyps)} converged on the reference"
        elif best_n < need:
            reason = (
                f"{best_n} of {len(xy)} local stems on reference stems ({inside} inside the "
                f"reference's stems, need {need})"
            )
        elif second_n >= init.ambiguity_ratio * best_n:
            reason = f"ambiguous: two placements with {best_n} and {second_n} stems"
        if (best_n, -second_n) >= (self.best.best_consensus, -self.best.second_consensus):
            self.best = Attempt(len(xy), best_n, second_n, reason or "placed")
        if reason:
            log.debug("placement attempt at frame %d: %s", latest.index, reason)
            return None
        n, _, _, T, lm, source = verified[0]
        log.info(
            "walk placed at frame %d (%.3f) by %s: %d of %d local stems on reference stems "
            "(second %d), x=%.2f y=%.2f yaw=%.1f deg",
            latest.index,
            latest.stamp,
            source,
            n,
            len(xy),
            second_n,
            T[0, 3],
            T[1, 3],
            np.degrees(np.arctan2(T[1, 0], T[0, 0])),
        )
        return Placement(T, lm, n, len(xy), len(hyps), second_n, source)

    def dropped(self) -> list[PendingFrame]:
        """Pending frames of earlier odometry segments (no pose can be chained to them)."""
        last = self.pending[-1]
        return [f for f in self.pending if f.segment != last.segment]


def _with_planar(T: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """T with its x, y and heading replaced (height, roll and pitch kept)."""
    out = T.copy()
    out[:3, :3] = rot_z(yaw - yaw_of(T)) @ T[:3, :3]
    out[:2, 3] = [x, y]
    return out


def _refine_on(tree, xy: np.ndarray, src: np.ndarray, T: np.ndarray) -> np.ndarray | None:
    """T refined in x, y and yaw by matching stems src (S,2) (frame) to xy (K,2) (tree over
    them) with shrinking gates; None when fewer than 3 or half of src match at the end."""
    for gate in (0.6, 0.3, 0.15):
        d, j = tree.query(transform_xy(T, src))
        ok = d < gate
        if ok.sum() < 3:
            return None
        fit = rigid_fit(src[ok], xy[j[ok]])
        T = _with_planar(T, fit[0, 2], fit[1, 2], yaw_of(fit))
    d, _ = tree.query(transform_xy(T, src))
    ok = d < 0.15
    return T if ok.sum() >= max(3, 0.5 * len(src)) else None


def _near(a: np.ndarray, b: np.ndarray) -> bool:
    """Two poses within 0.5 m and 3 deg: one placement."""
    d = np.linalg.inv(a) @ b
    yaw = abs(np.arctan2(d[1, 0], d[0, 0]))
    return bool(np.linalg.norm(d[:2, 3]) < 0.5 and yaw < np.radians(3.0))
