"""Fingerprint of the perception stages this round sped up or split (ground segmentation, range
image clusters, normal filter) on recorded scans, to show a refactoring leaves them bit-identical:
run it with two builds and compare the digests.

    PYTHONPATH=python:BUILD_A dev.sh py bench/perception_fingerprint.py BAG [BAG ...]
    PYTHONPATH=python:BUILD_B dev.sh py bench/perception_fingerprint.py BAG [BAG ...]

Every third scan of each bag (VLP-16 geometry) goes through perception_segment_ground,
perception_range_image_clusters (with its rings) and perception_normal_filter (on the non-ground
rows); one wide cloud of several scans side by side goes through the ground filter as a map cloud
would. Prints the SHA-256 of all outputs and the map cloud's ground count; then the SHA-256 of
every field of the Stems that `detect` gives on every second of the first 400 scans (VLP-16),
every diameter fit (circle, cylinder, silhouette) included, and the number of stems.
"""

from __future__ import annotations

import hashlib
import sys

import numpy as np

from forestslam import _core
from forestslam.io.readers import read_scans
from forestslam.perception.config import PerceptionConfig
from forestslam.perception.pipeline import detect, sensor_geometry

STEM_FIELDS = ("xy", "dbh", "z", "mean", "cov", "axis", "base_z", "ground", "breast_source")
FIT_FIELDS = ("valid", "radius", "centre", "axis", "inliers", "rms_m", "arc_coverage", "score")
FIT_FIELDS += ("radius_std", "multi_object_lines")


def main(bags: list[str]) -> str:
    digest = hashlib.sha256()

    def add(*arrays) -> None:
        for a in arrays:
            digest.update(np.ascontiguousarray(a).tobytes())

    geometry = sensor_geometry("vlp16")
    ground_cfg = _core.GroundConfig()
    seg_cfg, normal_cfg = _core.SegmentationConfig(), _core.NormalFilterConfig()
    wide = []
    for bag in bags:
        for k, scan in enumerate(read_scans(bag)):
            if k % 3:
                continue
            g = _core.perception_segment_ground(scan.points, ground_cfg)
            add(g.is_ground, g.grid.z, g.grid.origin)
            ring = None if scan.ring is None else scan.ring.astype(np.int32)
            clusters = _core.perception_range_image_clusters(scan.points, ring, geometry, seg_cfg)
            add(*(np.asarray(c) for c in clusters))
            rows = np.flatnonzero(~np.asarray(g.is_ground)).astype(np.int64)
            n = _core.perception_normal_filter(scan.points, rows, geometry.theta_v_rad, normal_cfg)
            add(np.asarray(n.kept), n.normals)
            if k % 30 == 0:
                wide.append(scan.points + np.array([k * 0.7, k * 0.3, 0.0]))
    if wide:
        g = _core.perception_segment_ground(np.vstack(wide), ground_cfg)
        add(g.is_ground, g.grid.z)
        ground = int(np.asarray(g.is_ground).sum())
        return f"{digest.hexdigest()} (map cloud: {ground} ground points)"
    return digest.hexdigest()


def stems_digest(bags: list[str], step: int = 2, scans: int = 400) -> str:
    digest, count = hashlib.sha256(), 0
    every_fit = PerceptionConfig()  # every estimate fitted, even those an earlier one decides
    every_fit.diameter.fit_all = True

    def add(x) -> None:
        digest.update(np.ascontiguousarray(np.asarray(x, dtype=np.float64)).tobytes())

    for bag in bags:
        for k, scan in enumerate(read_scans(bag)):
            if k >= scans:
                break
            if k % step:
                continue
            stems = detect(scan, "vlp16", every_fit)
            count += len(stems)
            for name in STEM_FIELDS:
                add(getattr(stems, name))
            for p in stems.points:
                add(p)
            for d in stems.diameters:
                for fit in (d.circle, d.cylinder, d.silhouette):
                    for name in FIT_FIELDS:
                        add(getattr(fit, name))
                for x in (d.dbh, d.dbh_std, d.centre, d.band_points):
                    add(x)
    return f"{digest.hexdigest()} ({count} stems)"


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print(main(sys.argv[1:]))
    print("stems:", stems_digest(sys.argv[1:]))
