"""Known answers for each DBH stage under LiDAR range noise on one-sided views: the circle fit
of a view (fit_circle vs fit_circle_rays), the per-scan stages of perception on stems with
ovality, bark roughness and polygonal sections at VLP-16 sampling, and the tree map's fused
DBH from windows of one-sided views."""

import numpy as np
import pytest

from forestslam import _core
from forestslam.mapping.config import MappingConfig
from forestslam.mapping.tree_map import TreeMap
from forestslam.perception import PerceptionConfig, detect
from forestslam.perception.stems import REPORT_MAX_DBH_STD_M
from forestslam.perception.synthetic_stems import ROUGH, ROUND, make_world, scan_stems


def one_sided_view(centre, r, origin, noise, rng, n=60):
    """Points on the side of a circle facing `origin`, each off along its beam by range noise."""
    to = np.asarray(centre) - origin
    d = np.linalg.norm(to)
    half = np.arcsin(r / d)
    b = np.arctan2(to[1], to[0]) + np.linspace(-half, half, n + 2)[1:-1]
    u = np.c_[np.cos(b), np.sin(b)]
    a = u @ to
    t = a - np.sqrt(np.maximum(r * r - (to @ to - a * a), 0.0))
    return origin + (t + rng.normal(0, noise, n))[:, None] * u


def test_range_model_circle_fit_is_unbiased_where_the_orthogonal_fit_shrinks():
    rng = np.random.default_rng(1)
    ortho, rays = [], []
    for k in range(30):
        r = 0.06 + 0.006 * k
        p = one_sided_view((7.0, 2.0), r, np.zeros(2), 0.03, rng, n=200)
        o = np.zeros_like(p)
        ortho.append(2 * _core.fit_circle(p).radius - 2 * r)
        rays.append(2 * _core.fit_circle_rays(p, o).radius - 2 * r)
    assert np.mean(ortho) < -0.01  # the bias this issue is about: > 1 cm DBH at 3 cm noise
    assert abs(np.mean(rays)) < 0.004


@pytest.mark.parametrize("style", [ROUND, ROUGH], ids=lambda s: s.name)
def test_per_scan_stages_on_shaped_stems(style):
    cfg = PerceptionConfig()
    cfg.diameter.fit_all = True
    errors = {"silhouette": [], "circle": [], "chosen": []}
    for seed, x in [(seed, x) for seed in (3, 4) for x in np.linspace(2.0, 18.0, 6)]:
        world = make_world(style, seed=seed, n=25, length_m=20.0)
        txy = np.array([[s.x, s.y] for s in world])
        i = int(10 * x)
        sxy = np.array([x, 0.0])
        stems = detect(scan_stems(world, sxy, style, noise_m=0.03, seed=i, gain=1.3), "vlp16", cfg)
        for k in range(len(stems)):
            d = np.linalg.norm(txy - sxy - stems.mean[k, :2], axis=1)
            j = int(np.argmin(d))
            if d[j] > 0.5 or np.linalg.norm(txy[j] - sxy) > 15:
                continue
            for m in ("silhouette", "circle"):
                fit = getattr(stems.diameters[k], m)
                if fit.valid:
                    errors[m].append(2 * fit.radius - world[j].dbh)
            errors["chosen"].append(stems.dbh[k] - world[j].dbh)
    assert min(len(e) for e in errors.values()) >= 100
    # Bias over the estimates within 10 cm of the truth (a stem merged with its neighbour in
    # one scan is a segmentation matter). The band circle with the orthogonal fit: -2.1 cm.
    err = {k: np.asarray(v)[np.abs(v) < 0.1] for k, v in errors.items()}
    # Measured: circle -1.2 / -1.0 cm (round / rough; -2.1 cm with the orthogonal fit on
    # round stems), silhouette -0.3 / -0.2 cm, chosen MAE 1.3 / 2.0 cm (target 2.5 cm).
    assert abs(np.mean(err["circle"])) < 0.015
    assert abs(np.mean(err["silhouette"])) < 0.008
    assert np.mean(np.abs(err["chosen"])) < 0.025


def test_tree_map_dbh_from_one_sided_windows():
    """A sensor passes stems on one side at 1 m/s, 10 Hz, 3 cm range noise: each window sees
    the same side; the fused DBH must not shrink."""
    rng = np.random.default_rng(4)
    stems = [((2.0 * i, 3.0 + (i % 3)), 0.08 + 0.03 * (i % 5)) for i in range(16)]
    errors = {}
    for rays in (False, True):
        # These views have no spread across the beams (no pose jitter): say so to the fit.
        tm = TreeMap(MappingConfig(dbh_lateral_sigma_m=0.002))
        if not rays:  # the same windows without view origins: the orthogonal fit
            tm._fit = _orthogonal_fit(tm)
        for s, x in enumerate(np.arange(-5.0, 35.0, 0.1)):
            T = np.eye(4)
            T[0, 3] = x
            ids, pts = [], []
            for j, (c, r) in enumerate(stems):
                if np.hypot(c[0] - x, c[1]) > 12:
                    continue
                xy = one_sided_view(c, r, np.array([x, 0.0]), 0.03, rng, n=8) - [x, 0.0]
                ids.append(j)
                pts.append(np.c_[xy, np.full(len(xy), 1.3)])
            base = np.zeros(len(ids))
            # Perception's per-scan DBH (its silhouettes): the stem test asks for one in most
            # scans; these windows are far narrower than 1.5x it, so it gates nothing (the
            # window circles alone are scored: window_dbh).
            scan_dbh = np.array([2 * stems[j][1] for j in ids])
            tm.add(s, T, np.array(ids), pts, base, base + 1.3, scan_dbh)
            tm.flush(s)
        tm.flush()
        errors[rays] = [tm.window_dbh(j)[0] - 2 * r for j, (_, r) in enumerate(stems)]
    # Measured on these 2.5 m windows of 8-point views: orthogonal -5.2 cm, range model
    # -1.9 cm (a residual bias left; some windows keep the orthogonal fit when their spread
    # does not look beam-aligned, see fitCircleRays and the report of issue 15).
    assert np.mean(errors[False]) < -0.03
    assert abs(np.mean(errors[True])) < 0.02
    assert abs(np.mean(errors[True])) < 0.4 * abs(np.mean(errors[False]))


def _orthogonal_fit(tm):
    from forestslam.mapping.tree_map import fit_band_circle

    def fit(tree):
        pts = np.concatenate(tree.band)
        tree.band, tree.origins, tree.n_band_scans = [], [], 0
        f = fit_band_circle(pts[:, :2], tm.cfg)
        if f is not None:
            tree.measurements.append((2 * f.radius, f.inliers * f.arc_coverage**2))

    return fit


def _detections_matched_to_truth(style):
    """Single VLP-16 scans (3 cm range noise) from 12 places along two worlds: each detected
    stem within 0.3 m of a true stem no further than 15 m, as (stems, k, true stem, its
    position relative to the sensor)."""
    for seed, x in [(seed, x) for seed in (3, 4) for x in np.linspace(2.0, 18.0, 6)]:
        world = make_world(style, seed=seed, n=25, length_m=20.0)
        sxy = np.array([x, 0.0])
        rel = np.array([[s.x, s.y] for s in world]) - sxy
        scan = scan_stems(world, sxy, style, noise_m=0.03, seed=int(10 * x), gain=1.3)
        stems = detect(scan, "vlp16")
        for k in range(len(stems)):
            d = np.linalg.norm(rel - stems.xy[k], axis=1)
            j = int(np.argmin(d))
            if d[j] <= 0.3 and np.linalg.norm(rel[j]) <= 15:
                yield stems, k, world[j], rel[j]


@pytest.mark.parametrize("style", [ROUND, ROUGH], ids=lambda s: s.name)
def test_per_scan_stem_centres_are_unbiased_in_range(style):
    """Stem centres (what SLAM observes) at VLP-16 sampling and 3 cm range noise: the distance
    from the sensor must not be short. Median measured: round -2.5 cm when the silhouette centre
    stood on the nearest range of its section (the minimum of noisy ranges), -0.2 cm now;
    rough +0.0 / +0.3 cm (fewer silhouettes accepted there)."""
    errors = [
        np.linalg.norm(stems.xy[k]) - np.linalg.norm(rel)
        for stems, k, _, rel in _detections_matched_to_truth(style)
    ]
    assert len(errors) >= 100
    assert abs(np.median(errors)) < 0.01


@pytest.mark.parametrize("style", [ROUND, ROUGH], ids=lambda s: s.name)
def test_per_scan_dbh_std_predicts_the_error(style):
    """dbh_std (angular sampling, scan-line spread, fit covariance) at VLP-16 sampling and 3 cm
    range noise: roughly calibrated (the ovality and polygons of rough stems are not in it),
    and the DBH a scan reports (sigma <= 2 cm) is the better part."""
    err, std = [], []
    for stems, k, tree, _ in _detections_matched_to_truth(style):
        if np.isfinite(stems.dbh[k]):
            err.append(abs(stems.dbh[k] - tree.dbh))
            std.append(stems.dbh_std[k])
    err, std = np.asarray(err), np.asarray(std)
    reported = std <= REPORT_MAX_DBH_STD_M
    # Measured (round / rough): 67 / 45 % within 1 sigma, 88 / 82 % reported, MAE of the
    # reported 1.4 / 2.7 cm, of the others 3.3 / 5.4 cm.
    assert len(err) >= 100
    assert 0.4 <= np.mean(err <= std) <= 0.85
    assert reported.mean() >= 0.6
    assert err[~reported].mean() > 1.2 * err[reported].mean()


def test_near_silhouettes_keep_their_edges():
    """Stems 2.5-6 m from a VLP-16 (3 cm range noise), round sections, one scan per place: the
    silhouette must not come out small. It did by 0.6 cm (1.0-1.6 cm on the simulator's loops,
    bench/dbh_near_range.py) when it was measured on the normal filter's one return per 5 cm
    voxel (the outermost returns of each scan line thinned away) and stood on each line's
    nearest range (the minimum of noisy ranges). Measured now: +0.02 cm over 89 stems."""
    errors = []
    for seed in range(6):
        world = make_world(ROUND, seed=seed, n=30, length_m=20.0, lane_m=2.5, depth_m=6.0)
        txy = np.array([[s.x, s.y] for s in world])
        for x in (5.0, 15.0):
            sxy = np.array([x, 0.0])
            stems = detect(scan_stems(world, sxy, ROUND, noise_m=0.03, seed=seed), "vlp16")
            for k in range(len(stems)):
                sil = stems.diameters[k].silhouette
                d = np.linalg.norm(txy - sxy - stems.xy[k], axis=1)
                j = int(np.argmin(d))
                if sil.valid and d[j] <= 0.3 and np.linalg.norm(txy[j] - sxy) <= 6.0:
                    errors.append(2 * sil.radius - world[j].dbh)
    errors = np.asarray(errors)
    assert len(errors) >= 40
    assert abs(np.mean(errors[np.abs(errors) < 0.1])) < 0.003


def test_explicit_breast_height_without_stem_points_gives_no_stem():
    """--breast-height-z where no stem has points (above every stem here) is no measurement:
    no stem, not a DBH from the SAC cylinder of points metres away. At the true breast
    height the same scan gives its stems with DBH."""
    world = make_world(ROUND, seed=1, n=20, length_m=10.0, depth_m=8.0)
    scan = scan_stems(world, np.array([5.0, 0.0]), ROUND, noise_m=0.03, seed=1)
    top = scan.points[:, 2].max()
    assert len(detect(scan, "vlp16", breast_height_z=top + 2.0)) == 0
    at_bh = detect(scan, "vlp16", breast_height_z=-1.8 + 1.3)  # ground 1.8 m below the sensor
    assert len(at_bh) >= 5 and np.isfinite(at_bh.dbh).mean() >= 0.8


def test_silhouette_cut_by_a_nearer_stem_is_not_taken():
    """A 40 cm stem 10 m away, partly hidden by a 12 cm stem at 4 m: the scan lines' widths end
    at the near stem's edge, not at its own. Before the occlusion check the silhouette gave
    -19 to -5 cm with a 1.4 cm sigma; now those lines are left out and the DBH (band circle)
    is within 4 cm and within 2 of its sigmas."""
    from forestslam.perception.synthetic_stems import make_stem

    rng = np.random.default_rng(0)
    for k, y in enumerate((0.15, 0.2, 0.25, 0.3)):
        far = make_stem(10.0, y, 0.40, ROUND, rng)
        world = [make_stem(4.0, 0.0, 0.12, ROUND, rng), far]
        stems = detect(scan_stems(world, np.zeros(2), ROUND, noise_m=0.03, seed=k), "vlp16")
        j = int(np.argmin(np.linalg.norm(stems.xy - [10.0, y], axis=1)))
        assert np.linalg.norm(stems.xy[j] - [10.0, y]) < 0.4
        err = abs(stems.dbh[j] - far.dbh)
        assert err < 0.045 and err < 2 * stems.dbh_std[j]


@pytest.mark.parametrize("distance", [8.0, 12.0])
def test_cluster_of_two_stems_gives_no_merged_dbh(distance):
    """A 20 cm and a 34 cm stem side by side, 40 cm apart across a VLP-16's view, which the
    segmentation merges into one cluster: every scan line spans both, and the silhouette gave
    a 68 cm DBH (on the simulator's loops such clusters made 40-80 cm silhouettes and most of
    the per-scan MAE on VLP-16 style b). The returns between them lie behind the front of the
    stem that width implies, so that cluster now has no DBH in this scan; each stem seen
    alone keeps its own."""
    from forestslam.perception.synthetic_stems import make_stem

    rng = np.random.default_rng(int(distance))
    pair = [make_stem(distance, -0.2, 0.20, ROUND, rng), make_stem(distance, 0.2, 0.34, ROUND, rng)]
    for seed in range(4):
        stems = detect(scan_stems(pair, np.zeros(2), ROUND, noise_m=0.03, seed=seed), "vlp16")
        assert len(stems) >= 1
        assert not np.any(stems.dbh > 0.45)  # no DBH wider than the larger stem (+ 11 cm)
    for stem in pair:
        alone = detect(scan_stems([stem], np.zeros(2), ROUND, noise_m=0.03, seed=1), "vlp16")
        assert len(alone) == 1 and abs(alone.dbh[0] - stem.dbh) < 0.03


def test_bright_bark_facing_the_sensor_keeps_its_silhouette():
    """A sensor whose gain puts many bark returns above the profile's intensity threshold
    (facing ones brightest, grazing edges dark): the filter takes most of each stem, and the
    silhouette must come from every return on the stem's surface, bright or not. On main the
    filtered stems gave fewer DBHs and a low bias (see the bounds' comment)."""
    errors, matched = [], 0
    for seed, x in [(seed, x) for seed in (3, 4) for x in np.linspace(2.0, 18.0, 9)]:
        world = make_world(ROUGH, seed=seed, n=25, length_m=20.0)
        txy = np.array([[s.x, s.y] for s in world])
        sxy = np.array([x, 0.0])
        scan = scan_stems(world, sxy, ROUGH, noise_m=0.03, seed=int(10 * x), gain=1.3)
        stems = detect(scan, "vlp16", PerceptionConfig())
        for k in range(len(stems)):
            d = np.linalg.norm(txy - sxy - stems.mean[k, :2], axis=1)
            j = int(np.argmin(d))
            if d[j] > 0.5 or np.linalg.norm(txy[j] - sxy) > 15:
                continue
            matched += 1
            if np.isfinite(stems.dbh[k]):
                errors.append(stems.dbh[k] - world[j].dbh)
    # As above: a stem merged with its neighbour in one scan is a segmentation matter.
    e = np.asarray(errors)
    e = e[np.abs(e) < 0.1]
    print(
        f"matched {matched}, with DBH {len(errors)}, within 10 cm {len(e)}, "
        f"bias {100 * e.mean():+.2f} cm, MAE {100 * np.abs(e).mean():.2f} cm"
    )
    # Measured: 285 of 296 within 10 cm, bias -0.12 cm, MAE 1.65 cm; main 263, -0.44, 1.98 cm.
    assert len(e) >= 0.93 * matched
    assert abs(e.mean()) < 0.003
    assert np.abs(e).mean() < 0.018
