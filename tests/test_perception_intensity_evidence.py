"""With `intensity_as_evidence` the intensity filter is evidence per cluster, not a cut before
the clustering (detector.cpp, refineWithEvidence; off by default): a sensor whose
gain puts the bark facing it above the profile's threshold must still see one stem per tree
with its DBH, and bright foliage beside a stem must stay out of it (geometry decides which
removed returns lie on the stem's surface)."""

import numpy as np

from forestslam.io.scan import Scan
from forestslam.perception import PerceptionConfig, detect
from forestslam.perception.synthetic_stems import ROUGH, ROUND, make_stem, scan_stems

EVIDENCE = PerceptionConfig(intensity_as_evidence=True)


def _pieces_and_errors(gain: float):
    """Per truth stem within 12 m of a lane of scans: detections within 1 m, and DBH errors."""
    pieces, errors = [], []
    for seed in (5, 6):
        rng = np.random.default_rng(seed)
        world = [
            make_stem(x, y, rng.uniform(0.15, 0.45), ROUGH, rng)
            for x, y in ((2.0, 4.0), (6.0, -5.0), (10.0, 7.0), (14.0, -3.5), (18.0, 9.0))
        ]
        txy = np.array([[s.x, s.y] for s in world])
        for x in np.linspace(0.0, 20.0, 6):
            sxy = np.array([x, 0.0])
            scan = scan_stems(world, sxy, ROUGH, noise_m=0.02, seed=int(10 * x) + seed, gain=gain)
            stems = detect(scan, "vlp16", EVIDENCE)
            for j in np.nonzero(np.linalg.norm(txy - sxy, axis=1) <= 12.0)[0]:
                d = np.linalg.norm(stems.xy - (txy[j] - sxy), axis=1) if len(stems) else []
                near = np.nonzero(np.asarray(d) < 1.0)[0]
                pieces.append(len(near))
                errors += [stems.dbh[k] - world[j].dbh for k in near if np.isfinite(stems.dbh[k])]
    return np.array(pieces), np.array(errors)


def test_bright_bark_at_high_gain_stays_one_stem_with_its_dbh():
    """Gain 1.5: most of each stem's returns lie above the threshold (the bark facing the
    sensor). Filtering them before the clustering left edge strips or nothing: on main 0.79 of
    the stems came out as one detection, DBH MAE 5.3 cm, worst -22.9 cm (one edge's piece).
    Measured with the removed returns as evidence: 0.93, MAE 1.55 cm, worst -4.2 cm."""
    pieces, errors = _pieces_and_errors(1.5)
    print(
        f"one piece {np.mean(pieces == 1):.2f}, none {np.mean(pieces == 0):.2f}, "
        f"DBH errors {len(errors)}: MAE {100 * np.abs(errors).mean():.2f} cm, "
        f"worst {100 * errors.min():+.1f} cm"
    )
    assert np.mean(pieces == 1) >= 0.9
    assert np.abs(errors).max() < 0.08
    assert np.abs(errors).mean() < 0.025


def _stem_with_clump(clump_intensity: float, seed: int = 1):
    """A round 30 cm stem 6 m ahead and a dense foliage clump beside it (0.25-0.75 m off its
    surface, 0.6-2.2 m up), scanned by a VLP-16; the clump's returns at `clump_intensity`."""
    rng = np.random.default_rng(seed)
    stem = make_stem(6.0, 0.0, 0.30, ROUND, rng)
    scan = scan_stems([stem], np.zeros(2), ROUND, noise_m=0.01, seed=seed)
    el = np.deg2rad(np.arange(-15.0, 16.0, 2.0))
    az = np.arange(-0.3, 0.3, np.deg2rad(0.2))
    e, a = np.meshgrid(el, az, indexing="ij")
    d = np.c_[(np.cos(e) * np.cos(a)).ravel(), (np.cos(e) * np.sin(a)).ravel(), np.sin(e).ravel()]
    # The clump: leaves at y 0.17-0.6 m (touching the stem of radius 0.15 m), x 5.6-6.4 m.
    r = rng.uniform(5.6, 6.4, len(d))
    p = d * r[:, None]
    inside = (p[:, 1] > 0.17) & (p[:, 1] < 0.6) & (p[:, 2] > -0.4) & (p[:, 2] < 1.2)
    inside &= rng.random(len(d)) < 0.7
    clump = p[inside]
    points = np.r_[scan.points, clump]
    intensity = np.r_[scan.intensity, np.full(len(clump), clump_intensity, np.float32)]
    return stem, Scan(0.0, points, intensity=intensity.astype(np.float32))


def test_bright_foliage_beside_a_stem_stays_out_of_it():
    """A bright clump touching a stem: one stem, its DBH that of the stem alone, and no stem
    made of the clump (its few darker returns give no evidence that it is bark)."""
    for seed in (1, 2, 3):
        stem, scan = _stem_with_clump(160.0, seed)
        stems = detect(scan, "vlp16", EVIDENCE)
        assert len(stems) == 1
        assert np.linalg.norm(stems.xy[0] - [6.0, 0.0]) < 0.1
        assert abs(stems.dbh[0] - stem.dbh) < 0.03


def _scan_with_shrubs(seed: int, bright_share: float = 0.6) -> tuple[Scan, int]:
    """Three round 30 cm stems and up to 8 shrubs (1-1.6 m clumps of leaves from the ground to
    2 m up, 3-12 m from a VLP-16-like sensor): 60 % of the leaf returns above the threshold,
    the rest below it, at random (foliage: no order across a scan line). Also the number of
    shrubs."""
    rng = np.random.default_rng(seed)
    stems = [make_stem(x, y, 0.30, ROUND, rng) for x, y in ((6.0, 3.0), (-5.0, -4.0), (2.0, -7.0))]
    scan = scan_stems(stems, np.zeros(2), ROUND, noise_m=0.01, seed=seed)
    el = np.deg2rad(np.arange(-15.0, 16.0, 2.0))
    az = np.arange(-np.pi, np.pi, np.deg2rad(0.2))
    e, a = np.meshgrid(el, az, indexing="ij")
    d = np.c_[(np.cos(e) * np.cos(a)).ravel(), (np.cos(e) * np.sin(a)).ravel(), np.sin(e).ravel()]
    points, intensity = [scan.points], [scan.intensity]
    shrubs = 0
    for _ in range(8):
        c = rng.uniform(-12.0, 12.0, 2)
        if np.linalg.norm(c) < 3.0:
            continue
        w = rng.uniform(1.0, 1.6)
        p = d * (np.linalg.norm(c) + rng.uniform(-w / 2, w / 2, len(d)))[:, None]
        inside = (np.abs(p[:, :2] - c).max(axis=1) < w / 2) & (p[:, 2] > -1.7) & (p[:, 2] < 0.3)
        leaves = p[inside & (rng.random(len(d)) < 0.5)]
        points.append(leaves)
        intensity.append(np.where(rng.random(len(leaves)) < bright_share, 160.0, 40.0))
        shrubs += 1
    cloud = np.concatenate(points)
    return Scan(0.0, cloud, intensity=np.concatenate(intensity).astype(np.float32)), shrubs


def test_dark_returns_among_bright_leaves_make_no_stem_of_their_own():
    """Shrubs whose leaves straddle the threshold: a stem found with the removed returns as
    evidence and not by the kept returns alone (0.3 m apart) needs the removed returns of a
    shrub to pass the rank test of removedFaceTheSensor, which a shrub does by chance at its
    one-sided level (about 2 %): at most that share of the shrubs. When the removed returns
    were filtered and clustered with the kept ones, dark leaves among bright ones made
    sapling-like stems: 18 extra stems in these 30 scenes (96 stems without the option, the
    false trees of the style-a loops, issue 15); measured now: 1 in 233 shrubs."""
    extra, found, shrubs = 0, 0, 0
    for seed in range(30):
        scan, n = _scan_with_shrubs(seed)
        shrubs += n
        off = detect(scan, "vlp16", PerceptionConfig(intensity_as_evidence=False))
        on = detect(scan, "vlp16", EVIDENCE)
        found += len(off)
        for xy in on.xy:
            extra += not len(off) or np.linalg.norm(off.xy - xy, axis=1).min() > 0.3
    print(f"extra stems {extra} in {shrubs} shrubs; {found} stems without the option")
    assert found >= 90  # the three stems of every scene at least
    assert extra <= 0.02 * shrubs
