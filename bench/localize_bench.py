"""Global localization benchmark (issue 7): Delaunay triangle stars against prior tree maps.

1. Simulated LiDAR views against the whole longleaf stand map (584 trees): trees within range of
   random drivable poses, trunk occlusion, detection dropout (higher for saplings), 5 cm noise,
   false trunks; 1 frame and 5 aggregated frames (odometry noise between frames).
2. Real: FORTLS plots. One global map of the 10 field-measured plots placed side by side; each
   plot's TLS-detected trees localized in it.
3. Speed: per query against a 2,000-tree map; map build time for 10,000 trees.

Run: PYTHONPATH=python:build/dev-NAME/python .venv/bin/python bench/localize_bench.py [--queries N]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from forestslam.geometry import planar_pose, rot2

DATA = Path(
    os.environ.get("FORESTSLAM_DATA")
    or Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
)


def load_stand(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N,2) positions and (N,) DBH in metres (NaN when the stand has none) of a stand CSV with
    a header naming x, y and optionally dbh_m (or dbh, metres; dbh_cm, centimetres). Quoted
    names (R's write.csv) and extra columns (a row-name column) are accepted."""
    import csv

    with open(path, newline="") as f:
        header = [h.strip().strip('"').strip("'").lower() for h in next(csv.reader(f))]
    if "x" not in header or "y" not in header:
        raise SystemExit(f"{path}: a stand CSV needs a header with columns x and y, got {header}")
    data = np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2)
    xy = data[:, [header.index("x"), header.index("y")]]
    dbh = np.full(len(xy), np.nan)
    for name, scale in (("dbh_m", 1.0), ("dbh", 1.0), ("dbh_cm", 0.01)):
        if name in header:
            dbh = data[:, header.index(name)] * scale
            break
    ok = np.isfinite(xy).all(axis=1)
    return np.ascontiguousarray(xy[ok]), dbh[ok]


# The second stand of the `sim` part: a seeded Thomas-clustered stand at the density of the
# issue's 3,604-tree stand (probably spatstat's `bei`: 3,604 trees on 1000 m x 500 m, strongly
# clustered; not in ../shared/data), made by the simulator's stand generator. Positions only,
# as bei (its rows use the default shadow DBH below and carry no DBH evidence).
CLUSTERED_STAND = dict(
    size_m=(1000.0, 500.0),
    process="clustered",
    density_per_ha=72.08,
    cluster_radius_m=30.0,
    trees_per_cluster=70.0,
    min_spacing_m=1.0,
)
SHADOW_DBH_M = 0.3  # occlusion shadow of trees without a DBH


def stand_by_name(name: str) -> tuple[str, np.ndarray, np.ndarray]:
    """(label, xy, dbh) of a `--stand`: a shared stand's name (longleaf, spruces), 'clustered'
    (the seeded bei-density stand above), 'clustered-dbh' (the same with the generator's
    DBHs: occlusion, sapling dropout and DBH evidence follow them) or a CSV file x,y[,dbh_m]."""
    if name in ("clustered", "clustered-dbh"):
        from forestslam.sim.stand import load_stand as generate

        stand = generate("generated", seed=16, **CLUSTERED_STAND)
        label = f"{name} (synthetic Thomas, 1000 x 500 m, bei's density, seed 16)"
        if name == "clustered-dbh":
            return label, stand.xy, stand.dbh
        return label, stand.xy, np.full(len(stand.xy), np.nan)
    path = DATA / "stands" / f"{name}.csv"
    path = path if path.is_file() else Path(name)
    if not path.is_file():
        raise SystemExit(f"--stand {name}: neither a shared stand nor a CSV file")
    xy, dbh = load_stand(path)
    return (name if path.parent == DATA / "stands" else str(path)), xy, dbh


def visible_trees(
    xy: np.ndarray,
    dbh: np.ndarray,
    pos: np.ndarray,
    rng: np.random.Generator,
    max_range: float,
    dropout: float,
    sapling_dropout: float,
) -> np.ndarray:
    """Indices of trees a LiDAR at pos would detect: in range, not hidden behind a closer trunk
    (shadow of radius dbh/2 + 0.15 m for branches), minus random detection misses."""
    d = xy - pos
    r = np.hypot(d[:, 0], d[:, 1])
    cand = np.flatnonzero((r < max_range) & (r > 0.5))
    cand = cand[np.argsort(r[cand])]
    bearing = np.arctan2(d[cand, 1], d[cand, 0])
    shadow = np.where(np.isfinite(dbh[cand]), dbh[cand], SHADOW_DBH_M)
    half = np.arcsin(np.clip((shadow / 2 + 0.15) / r[cand], 0, 1))
    diff = np.abs((bearing[None, :] - bearing[:, None] + np.pi) % (2 * np.pi) - np.pi)
    # occluded[j]: some closer tree i (i < j) covers the bearing of j.
    covers = (diff < half[:, None]) & np.tri(len(cand), k=-1, dtype=bool).T
    hidden = covers.any(axis=0)
    p_miss = np.where(dbh[cand] < 0.1, sapling_dropout, dropout)
    seen = ~hidden & (rng.uniform(size=len(cand)) >= p_miss)
    return cand[seen]


def drivable_pose(xy: np.ndarray, rng: np.random.Generator, lo, hi, steps: np.ndarray):
    """A start position and heading whose path of `steps` metres keeps 1.5 m off every trunk
    and inside [lo, hi] (scalars, or (2,) per axis)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(xy)
    while True:
        start = rng.uniform(lo, hi, 2)
        heading = rng.uniform(-math.pi, math.pi)
        path = start + np.outer(steps, [math.cos(heading), math.sin(heading)])
        if ((path >= lo) & (path <= hi)).all() and (tree.query(path)[0] > 1.5).all():
            return path, heading


def working_pose(xy: np.ndarray, rng: np.random.Generator, lo, hi, steps: np.ndarray, reach):
    """A path whose last position is where a forest machine works: within crane reach
    (`reach` = (min, max) metres) of a tree drawn uniformly from the stand (so poses follow the
    trees: inside the clusters, not in the gaps between them), arrived at along a straight path
    of `steps` metres, every position 1.5 m off every trunk and inside [lo, hi]."""
    from scipy.spatial import cKDTree

    tree = cKDTree(xy)
    while True:
        r = rng.uniform(*reach)
        a, heading = rng.uniform(-math.pi, math.pi, 2)
        last = xy[rng.integers(len(xy))] + r * np.array([math.cos(a), math.sin(a)])
        path = last + np.outer(steps - steps[-1], [math.cos(heading), math.sin(heading)])
        if ((path >= lo) & (path <= hi)).all() and (tree.query(path)[0] > 1.5).all():
            return path, heading


@dataclass
class Drive:
    """The frames of one simulated query: per frame its trunks (K_i,2) in the sensor frame, their
    measured DBH (K_i,) and the odometry pose (4,4) T_world_sensor; the last frame's true planar
    pose (x, y, yaw)."""

    xys: list
    dbhs: list
    poses: list
    truth: tuple


def simulate_query(xy, dbh, rng, frames, args, lo=None, hi=None):
    """Local trunks (K,2) in the last frame's sensor frame, its true pose (x, y, yaw), the
    trunks' measured DBH (K,) (NaN where not measured) and the frames each was seen in (K,):
    `frames` simulated frames aggregated."""
    return aggregate_view(simulate_drive(xy, dbh, rng, frames, args, lo, hi), args)


def simulate_drive(xy, dbh, rng, frames, args, lo=None, hi=None) -> Drive:
    """`frames` frames `args.spacing` m apart along a drivable straight path (poses at least
    `args.margin` inside the stand's bounding box unless lo, hi are given; uniform there, or
    with `args.pose_model` 'working' ending within crane reach of a tree); their odometry poses
    carry a random-walk error (2 cm, 0.2 deg per frame). False trunks: `args.false_trunks`
    persistent objects near the path (stumps, posts: seen like trees) plus
    `args.transient_false` per frame on average (clutter that does not repeat). DBH per
    detection (drawn from `args.dbh_rng`, so the positions do not depend on it): the true one
    plus N(0, `args.dbh_noise`), a gross error (0.05-0.8 m) with `args.dbh_outliers`, none with
    `args.dbh_missing`."""
    lo = xy.min(axis=0) + args.margin if lo is None else lo
    hi = xy.max(axis=0) - args.margin if hi is None else hi
    steps = args.spacing * np.arange(frames)
    if getattr(args, "pose_model", "uniform") == "working":
        path, heading = working_pose(xy, rng, lo, hi, steps, args.reach)
    else:
        path, heading = drivable_pose(xy, rng, lo, hi, steps)
    n_fake = rng.poisson(args.false_trunks)
    rr = args.range * np.sqrt(rng.uniform(size=n_fake))
    aa = rng.uniform(-math.pi, math.pi, n_fake)
    fakes = path[-1] + np.column_stack([rr * np.cos(aa), rr * np.sin(aa)])
    drng = args.dbh_rng
    fake_dbh = drng.uniform(0.05, 0.5, n_fake)
    drive = Drive([], [], [], ())
    drift = np.zeros(3)
    for k, pos in enumerate(path):
        yaw = heading + rng.normal(0, 0.05)
        idx = visible_trees(xy, dbh, pos, rng, args.range, args.dropout, args.sapling_dropout)
        near_fake = np.hypot(*(fakes - pos).T) < args.range
        fake_seen = fakes[near_fake]
        d = np.vstack([xy[idx], fake_seen]) - pos
        local = d @ rot2(yaw)  # world offsets in the frame turned by yaw
        local += rng.normal(0, args.noise, local.shape)
        nt = rng.poisson(args.transient_false)
        rt = args.range * np.sqrt(rng.uniform(size=nt))
        at = rng.uniform(-math.pi, math.pi, nt)
        local = np.vstack([local, np.column_stack([rt * np.cos(at), rt * np.sin(at)])])
        true_dbh = np.concatenate([dbh[idx], fake_dbh[near_fake], drng.uniform(0.05, 0.5, nt)])
        drive.dbhs.append(measured_dbh(true_dbh, drng, args))
        if k > 0:
            drift += [rng.normal(0, 0.02), rng.normal(0, 0.02), rng.normal(0, math.radians(0.2))]
        if k == len(path) - 1:
            drift[:] = 0  # the local frame is the last frame: its odometry pose is the reference
            drive.truth = (pos[0], pos[1], yaw)
        drive.poses.append(planar_pose(pos[0] + drift[0], pos[1] + drift[1], yaw + drift[2]))
        drive.xys.append(local)
    return drive


def aggregate_view(drive: Drive, args, last: int | None = None):
    """(local trunks (K,2), true pose, DBH (K,), frames seen in (K,)) of the last `last` frames
    of a drive (all when None) aggregated by odometry as `forestslam localize --frames N` does;
    a trunk seen in several frames gets the median of its DBH measurements."""
    from scipy.spatial import cKDTree

    from forestslam.localization import LocalizationConfig, aggregate_stems

    n = len(drive.xys) if last is None else last
    xys, poses, dbhs = drive.xys[-n:], drive.poses[-n:], drive.dbhs[-n:]
    config = LocalizationConfig(min_observations=args.min_observations)
    centres, observations = aggregate_stems(xys, poses, config, return_observations=True)
    # Each aggregated trunk's DBH: the median of the detections merged into it.
    T_last = np.linalg.inv(poses[-1])
    det = np.vstack(
        [
            (np.column_stack([p, np.zeros(len(p)), np.ones(len(p))]) @ (T_last @ T).T)[:, :2]
            for p, T in zip(xys, poses, strict=True)
        ]
    )
    det_dbh = np.concatenate(dbhs)
    near = cKDTree(det).query_ball_point(centres, config.merge_radius_m + 1e-6)
    with np.errstate(all="ignore"):
        centre_dbh = np.array(
            [np.nanmedian(det_dbh[n]) if np.isfinite(det_dbh[n]).any() else np.nan for n in near]
        )
    return centres, drive.truth, centre_dbh, observations


def measured_dbh(true_dbh: np.ndarray, rng: np.random.Generator, args) -> np.ndarray:
    """One frame's DBH estimates: noisy, sometimes grossly wrong, sometimes missing."""
    out = true_dbh + rng.normal(0, args.dbh_noise, len(true_dbh))
    gross = rng.uniform(size=len(out)) < args.dbh_outliers
    out[gross] = rng.uniform(0.05, 0.8, gross.sum())
    out[rng.uniform(size=len(out)) < args.dbh_missing] = np.nan
    return np.maximum(out, 0.02)


def pose_error(loc, truth):
    dxy = math.hypot(loc.x - truth[0], loc.y - truth[1])
    dyaw = abs(math.degrees(math.remainder(loc.yaw - truth[2], 2 * math.pi)))
    return dxy, dyaw


def run_simulated(args) -> None:
    """Simulated queries on every `--stand` (default: longleaf and the bei-density clustered
    stand), whole stand as the map."""
    from forestslam.localization import build_map

    for name in args.stand:
        label, xy, dbh = stand_by_name(name)
        has_dbh = bool(np.isfinite(dbh).any())
        tree_map = build_map(xy, dbh if has_dbh else None)
        extent = np.ptp(xy, axis=0)
        print(
            f"\n== Simulated queries against {label}: {len(xy)} trees over {extent[0]:.0f} x "
            f"{extent[1]:.0f} m ({tree_map}) =="
        )
        print_simulated_protocol(args, has_dbh)
        for max_range in args.ranges:
            args.range = max_range
            run_simulated_range(args, xy, dbh, tree_map, has_dbh)
    print(
        "targets (issue 16): 1-frame views >= 99 % right, 0 wrong. The issue's 189/200 = 94.5 % "
        "was measured on a 3,604-tree stand (not in ../shared/data; probably spatstat's bei) "
        "with the localizer before the acceptance test (5c892bf): on the same 1-frame 20 m views "
        "(seed 7) it gets 92.0 % (clustered) and 81.7 % (a bei-like CSV) of 'working' poses but "
        "40.0 % and 32.0 % of uniform ones, so the issue's queries were near trees; run "
        "`--stand FILE.csv` (x,y[,dbh_m]) on it. The '1>5' rows are `forestslam "
        "localize`'s default for scans (--frames 1, localization.retry_frames 5, "
        "retry_keyframe_distance_m 3: a rejected 1-frame query is retried once with the last "
        "5 frames >= 3 m apart aggregated by odometry); the 1-frame rows are --retry-frames 0 "
        "(the 1-frame rows are not relabelled); the 5-frame rows --frames 5 "
        "--keyframe-distance-m 3"
    )


def print_simulated_protocol(args, has_dbh: bool) -> None:
    print(
        f"queries: {args.queries} per row, drivable poses (1.5 m off every trunk) >= "
        f"{args.margin} m inside the stand's bounding box: 'uniform' anywhere there (half of a "
        "clustered stand's poses fall in its gaps), 'working' within crane reach "
        f"({args.reach[0]:g}-{args.reach[1]:g} m) of a tree drawn uniformly from the stand (where "
        "a forest machine works: poses follow the trees); view: trunks within the range, "
        "occlusion by closer trunks, dropout "
        f"{args.dropout:.0%} (saplings dbh<0.1 m {args.sapling_dropout:.0%}), noise "
        f"{args.noise} m, false trunks ~{args.false_trunks} persistent + "
        f"~{args.transient_false}/frame transient; frames {args.spacing} m apart with odometry "
        "noise (2 cm, 0.2 deg per frame); an aggregated view passes the frames each trunk was "
        "seen in (localize observations=)"
    )
    if has_dbh:
        print(
            f"query DBH (rows 'xy+dbh'): true + N(0, {args.dbh_noise} m), "
            f"{args.dbh_outliers:.0%} gross errors, {args.dbh_missing:.0%} missing; rows 'xy': "
            "positions only (same views)"
        )
    else:
        print("the stand has no DBH: positions only")
    print(
        f"{'poses':>7} {'range m':>7} {'frames':>6} {'input':>6} {'queries':>7} {'success':>8} "
        f"{'rejected':>8} {'wrong acc':>9} {'median err m':>12} {'median deg':>10} "
        f"{'trunks':>6} {'map':>4} {'ms/query':>8} {'<=3 map':>7} {'success >=4 map':>15} "
        f"{'4 map: right':>12} {'success >=5 map':>15} {'retried':>7}"
    )
    print(
        "'trunks': median local trunks of the (first) view; 'map': median map trunks in it; "
        "'<=3 map': views holding at most 3 trunks of the map (within 0.5 m of one under the true "
        "pose; for '1>5' the 1-frame view): 3 points give only a triangle's shape, not testable "
        "against chance, so they are rejected by design; 'success >=4 map': success among the "
        "other views; '4 map: right': right / views holding exactly 4 (a triangle and one more "
        "trunk: weak evidence); 'success >=5 map': success among views holding 5 or more; "
        "'retried': rejected 1-frame queries retried with 5 frames"
    )


def run_simulated_range(args, xy, dbh, tree_map, has_dbh: bool) -> None:
    """The rows of one range: each of `args.frames` (default 1 and 5 frames), and for the most
    frames 1 frame retried with them when rejected (those drives' last frame alone first)."""
    for model in args.poses:
        args.pose_model = model  # same seeds for each model: the uniform rows stay as they were
        for frames in args.frames:
            rng = np.random.default_rng(args.seed + frames)
            args.dbh_rng = np.random.default_rng(args.seed + 50 + frames)
            drives = [simulate_drive(xy, dbh, rng, frames, args) for _ in range(args.queries)]
            attempts = {str(frames): [[aggregate_view(d, args)] for d in drives]}
            if frames > 1 and frames == max(args.frames):
                attempts[f"1>{frames}"] = [
                    [aggregate_view(d, args, 1), aggregate_view(d, args)] for d in drives
                ]
            for label, queries in attempts.items():
                for with_dbh in (False, True) if has_dbh else (False,):
                    print_simulated_row(tree_map, queries, with_dbh, args.range, label, model)
        if len(args.chain) > 2:
            run_chain_rows(args, xy, dbh, tree_map, has_dbh, model)
    args.pose_model = "uniform"  # the absent places' drives


def chain_drives(xy, dbh, args, seed: int) -> list:
    """`args.queries` drives of max(args.chain) frames (own random streams, so the rows above
    stay as they were): the chain's windows are their last n frames."""
    rng = np.random.default_rng(seed)
    dbh_rng, args.dbh_rng = args.dbh_rng, np.random.default_rng(seed + 1)
    drives = [simulate_drive(xy, dbh, rng, args.chain[-1], args) for _ in range(args.queries)]
    args.dbh_rng = dbh_rng
    return drives


def run_chain_rows(args, xy, dbh, tree_map, has_dbh: bool, model: str) -> None:
    """'Keep driving until accepted': each drive of max(chain) frames queried on its last n
    frames for n in the chain until one is accepted; the 1>5 rows of the same drives (the
    CLI's single retry) beside it, and the chain with its significance level spent across its
    looks (`chain_significance`)."""
    drives = chain_drives(xy, dbh, args, args.seed + 1000 + args.chain[-1])
    label = ">".join(map(str, args.chain))
    print(
        f"{model:>7} chain: {args.queries} drives of {args.chain[-1]} frames {args.spacing:g} m "
        f"apart (own seeds); '1>5' the CLI's single retry and '{label}' keeping on driving "
        "until accepted, on the same drives; '*': each look at the significance spent across "
        "the looks (chain_significance)"
    )
    windows = {n: [aggregate_view(d, args, n) for d in drives] for n in args.chain}
    chains = {"1>5": [1, 5], ">".join(map(str, args.chain)): args.chain}
    for label, chain in chains.items():
        queries = [[windows[n][i] for n in chain] for i in range(len(drives))]
        for with_dbh in (False, True) if has_dbh else (False,):
            for spent in (False, True) if len(chain) > 2 else (False,):
                config = chain_config(args, len(chain) if spent else 1)
                steps = print_simulated_row(
                    tree_map,
                    queries,
                    with_dbh,
                    args.range,
                    label + ("*" if spent else ""),
                    model,
                    config,
                )
                print_chain_needs(steps, chain, args.spacing)


def chain_config(args, looks: int):
    """The localizer's config for a chain of `looks` looks (the default's for 1)."""
    from forestslam.localization import LocalizationConfig, chain_significance

    config = LocalizationConfig()
    config.min_significance = chain_significance(config.min_significance, looks)
    return config


def print_chain_needs(steps: list, chain: list, spacing: float) -> None:
    """Under a chain row: the step each query was accepted at, frames and metres driven."""
    acc = [s for s in steps if s is not None]
    if not acc:
        print(f"{'':>7} accepted at no step of {chain}")
        return
    frames = np.array([chain[s] for s in acc])
    per_step = ", ".join(f"{n} fr: {sum(s == k for s in acc)}" for k, n in enumerate(chain))
    print(
        f"{'':>7} accepted at step ({per_step}); mean frames {frames.mean():.2f}, mean metres "
        f"driven {spacing * (frames - 1).mean():.1f} (budget {spacing * (chain[-1] - 1):g} m); "
        f"still rejected at the end {1 - len(acc) / len(steps):.1%}"
    )


def in_view(map_tree, local: np.ndarray, truth) -> int:
    """Map trunks in a view: local trunks within 0.5 m of one under the true pose."""
    world = local @ rot2(truth[2]).T + np.asarray(truth[:2])
    d, j = map_tree.query(world, distance_upper_bound=0.5)
    return len(set(j[np.isfinite(d)].tolist()))


def print_simulated_row(
    tree_map, queries, with_dbh, max_range, frames: str, poses: str, config=None
) -> list:
    """One row: each query is a list of views (local, truth, dbh) tried in turn until one is
    accepted (a retry after a rejection). Returns per query the index of the accepted view
    (None: all rejected)."""
    from scipy.spatial import cKDTree

    from forestslam.localization import localize

    map_tree = cKDTree(tree_map.xy)
    ok = rej = wrong = retried = 0
    errs, degs, trunks, times = [], [], [], []
    seen, right = [], []  # per query: map trunks in the (first) view, answered right
    steps = []  # per query: the view accepted (None: none)
    for views in queries:
        truth = views[0][1]
        seen.append(in_view(map_tree, views[0][0], truth))
        right.append(False)
        for attempt, (local, _truth, local_dbh, seen_in) in enumerate(views):
            c0 = time.process_time()
            loc = localize(
                tree_map,
                local,
                config,
                local_dbh_m=local_dbh if with_dbh else None,
                observations=seen_in,
            )
            times.append(1e3 * (time.process_time() - c0))
            if attempt == 0:
                trunks.append(len(local))
            retried += attempt > 0
            if loc.accepted:
                break
        steps.append(attempt if loc.accepted else None)
        if loc.rejected:
            rej += 1
            continue
        e, d = pose_error(loc, truth)
        if e < 0.5 and d < 2.0:
            ok += 1
            right[-1] = True
            errs.append(e)
            degs.append(d)
        else:
            wrong += 1
    n = len(queries)
    seen, right = np.array(seen), np.array(right)

    def rate(views: np.ndarray) -> str:
        return f"{right[views].mean():.1%}" if views.any() else "-"

    print(
        f"{poses:>7} {max_range:>7.0f} {frames:>6} {'xy+dbh' if with_dbh else 'xy':>6} {n:>7} "
        f"{ok / n:>8.1%} {rej / n:>8.1%} {wrong / n:>9.1%} "
        f"{np.median(errs) if errs else float('nan'):>12.3f} "
        f"{np.median(degs) if degs else float('nan'):>10.2f} {np.median(trunks):>6.0f} "
        f"{np.median(seen):>4.0f} {np.mean(times):>8.2f} {(seen <= 3).sum():>7} "
        f"{rate(seen >= 4):>15} "
        f"{f'{right[seen == 4].sum()}/{(seen == 4).sum()}':>12} {rate(seen >= 5):>15} {retried:>7}"
    )
    return steps


def count_absent(name, frames, tree_map, drive, args, totals):
    """Localize `args.absent_queries` queries of a place not in `tree_map` (`drive()` simulates
    one), with positions only and with DBH, and (several frames) retried: the last frame alone
    first, the aggregated frames when it is rejected; print the row and add to `totals`
    (queries, accepted xy, accepted xy+dbh, retried queries, accepted with retry xy, xy+dbh)."""
    from forestslam.localization import localize

    acc = tri = acc_dbh = acc_retry = acc_retry_dbh = 0
    for _ in range(args.absent_queries):
        d = drive()
        local, _truth, local_dbh, seen_in = aggregate_view(d, args)
        loc = localize(tree_map, local, observations=seen_in)
        acc += loc.accepted
        tri += loc.accepted and loc.stage == "triangle"
        loc_dbh = localize(tree_map, local, local_dbh_m=local_dbh, observations=seen_in)
        acc_dbh += loc_dbh.accepted
        if frames > 1:
            first, _truth, first_dbh, _seen = aggregate_view(d, args, 1)
            acc_retry += localize(tree_map, first).accepted or loc.accepted
            acc_retry_dbh += (
                localize(tree_map, first, local_dbh_m=first_dbh).accepted or loc_dbh.accepted
            )
    retry = f"{acc_retry:>7} {acc_retry_dbh:>7}" if frames > 1 else f"{'-':>7} {'-':>7}"
    print(
        f"{name:>28} {args.range:>7.0f} {frames:>6} {args.absent_queries:>7} {acc:>8} {tri:>8} "
        f"{acc_dbh:>10} {retry}"
    )
    totals[0] += args.absent_queries
    totals[1] += acc
    totals[2] += acc_dbh
    if frames > 1:
        totals[3] += args.absent_queries
        totals[4] += acc_retry
        totals[5] += acc_retry_dbh


def halves(name: str, xy: np.ndarray, args) -> dict:
    """A stand split at its median x: (map trunks, x range of the query poses) of both ways,
    the poses >= range + 5 m from the boundary, so no view reaches the mapped half."""
    mid = float(np.median(xy[:, 0]))
    return {
        f"{name} east in west half": (
            xy[:, 0] < mid,
            (mid + args.range + 5, float(xy[:, 0].max()) - 5),
        ),
        f"{name} west in east half": (
            xy[:, 0] >= mid,
            (float(xy[:, 0].min()) + 5, mid - args.range - 5),
        ),
    }


def run_simulated_absent(args) -> None:
    """Queries from places that are not in the map; every acceptance is wrong.
    a) longleaf split in halves: the map holds one half, the queries are driven in the other
       (poses >= range + 5 m from the boundary, so no view reaches the mapped half);
    b) spruces (a denser, different stand) queried in the whole longleaf map;
    c) synthetic stands (uniform, 1 m minimum spacing, densities 0.01-0.05 /m^2) in longleaf;
    d) the bei-density clustered stand split in halves, and longleaf queried in it;
    e) every other `--stand` (a CSV, e.g. bei) split in halves."""
    from forestslam.localization import build_map

    args.range = args.ranges[0]
    xy, dbh = load_stand(DATA / "stands" / "longleaf.csv")
    sp_xy, sp_dbh = load_stand(DATA / "stands" / "spruces.csv")
    rng = np.random.default_rng(args.seed + 100)
    print("\n== Absent places (simulated views; accepted = wrong) ==")
    print(
        "'retry': the 5-frame drive's last frame alone first, its 5 frames when rejected "
        "(--retry-frames 5): two tests per query"
    )
    if len(args.chain) > 2:
        print(
            f"chain rows: drives of {args.chain[-1]} frames {args.spacing:g} m apart, looks on "
            f"their last {args.chain} frames in turn (as the sim rows); '*': each look tested at "
            "the significance spent across the looks (chain_significance)"
        )
    print(
        f"{'case':>28} {'range m':>7} {'frames':>6} {'queries':>7} {'accepted':>8} {'triangle':>8} "
        f"{'acc w/ dbh':>10} {'retry':>7} {'r w/dbh':>7}"
    )
    args.dbh_rng = np.random.default_rng(args.seed + 150)
    # The chain's drives: own streams, so the rows of the 1- and 5-frame drives stay as they were.
    args.chain_rng = np.random.default_rng(args.seed + 200)
    args.chain_dbh_rng = np.random.default_rng(args.seed + 250)
    args.chain_totals = np.zeros(7, dtype=int)
    whole = build_map(xy, dbh)
    totals = [0] * 6
    for name, (in_map, (xlo, xhi)) in halves("longleaf", xy, args).items():
        tree_map = build_map(xy[in_map], dbh[in_map])
        for frames in (1, 5):
            drive = partial(simulate_drive_x, xy, dbh, rng, frames, args, xlo, xhi)
            count_absent(name, frames, tree_map, drive, args, totals)
        chain_absent(
            name,
            tree_map,
            partial(simulate_drive_x, xy, dbh, xlo=xlo, xhi=xhi, whole_path=True),
            args,
        )
    others = {"spruces in longleaf": (sp_xy, sp_dbh, 2.0)}
    for density in (0.01, 0.02, 0.05):
        sxy = random_stand(3000, density, rng)
        others[f"uniform {density}/m2 in longleaf"] = (sxy, np.full(len(sxy), 0.3), 20.0)
    for name, (oxy, odbh, margin) in others.items():
        lo, hi = float(oxy.min()) + margin, float(oxy.max()) - margin
        for frames in (1, 5):
            drive = partial(simulate_drive, oxy, odbh, rng, frames, args, lo, hi)
            count_absent(name, frames, whole, drive, args, totals)
        chain_absent(name, whole, partial(simulate_drive, oxy, odbh, lo=lo, hi=hi), args)
    run_clustered_absent(args, xy, dbh, totals)
    for name in args.stand:
        if name not in ("longleaf", "clustered"):
            run_stand_absent(args, name, totals)
    print_chain_absent_total(args)
    total, total_retry = max(totals[0], 1), max(totals[3], 1)
    print(
        f"absent places accepted: xy {totals[1]}/{total} = {totals[1] / total:.2%}, with DBH "
        f"{totals[2]}/{total} = {totals[2] / total:.2%}; retried 1>5 (5-frame rows): xy "
        f"{totals[4]}/{total_retry} = {totals[4] / total_retry:.2%}, with DBH "
        f"{totals[5]}/{total_retry} = {totals[5] / total_retry:.2%} (target <= 0.5 %)"
    )


def chain_absent(name: str, tree_map, simulate, args) -> None:
    """The chain's absent row of one case: `args.absent_queries` drives of max(chain) frames
    (own random streams: the rows above stay as they were), `simulate(rng=, frames=, args=)`
    simulates one; a query is accepted when ANY look accepts. Counts 1>5 on the same drives,
    the chain, and the chain with its significance spent across its looks ('*')."""
    from forestslam.localization import localize

    if len(args.chain) < 3:
        return
    configs = (chain_config(args, 1), chain_config(args, len(args.chain)))
    counts = np.zeros((2, 3), dtype=int)  # [xy, xy+dbh] x [1>5, chain, chain*]
    dbh_rng, args.dbh_rng = args.dbh_rng, args.chain_dbh_rng
    for _ in range(args.absent_queries):
        d = simulate(rng=args.chain_rng, frames=args.chain[-1], args=args)
        views = [aggregate_view(d, args, n) for n in args.chain]
        for k, with_dbh in enumerate((False, True)):
            acc = np.array(
                [
                    [
                        localize(
                            tree_map,
                            v[0],
                            c,
                            local_dbh_m=v[2] if with_dbh else None,
                            observations=v[3],
                        ).accepted
                        for v in views
                    ]
                    for c in configs
                ]
            )
            first_two = [i for i, n in enumerate(args.chain) if n in (1, 5)]
            counts[k] += [acc[0, first_two].any(), acc[0].any(), acc[1].any()]
    args.dbh_rng = dbh_rng
    args.chain_totals += np.hstack([[args.absent_queries], counts.ravel()])
    label = ">".join(map(str, args.chain))
    print(
        f"{name:>28} {args.range:>7.0f} {label:>6} {args.absent_queries:>7} chain looks "
        f"accepted (any): 1>5 {counts[0, 0]}, {label} {counts[0, 1]}, {label}* {counts[0, 2]}; "
        f"with DBH {counts[1, 0]}, {counts[1, 1]}, {counts[1, 2]}"
    )


def print_chain_absent_total(args) -> None:
    if len(args.chain) < 3:
        return
    t = args.chain_totals
    n = max(int(t[0]), 1)
    label = ">".join(map(str, args.chain))
    names = ("1>5", label, label + "*")
    xy = ", ".join(f"{m} {t[1 + i]}/{n} = {t[1 + i] / n:.2%}" for i, m in enumerate(names))
    dbh = ", ".join(f"{m} {t[4 + i]}/{n} = {t[4 + i] / n:.2%}" for i, m in enumerate(names))
    print(f"absent places accepted by ANY look of a chain (same drives): xy {xy}; with DBH {dbh}")


def run_clustered_absent(args, ll_xy, ll_dbh, totals) -> None:
    """Absent places of the bei-density clustered stand (its own random stream: the rows above
    stay as they were): its halves, and longleaf's views in the whole of it."""
    from forestslam.localization import build_map

    rng = np.random.default_rng(args.seed + 120)
    _label, xy, dbh = stand_by_name("clustered")
    for name, (in_map, (xlo, xhi)) in halves("clustered", xy, args).items():
        tree_map = build_map(xy[in_map])
        for frames in (1, 5):
            drive = partial(simulate_drive_x, xy, dbh, rng, frames, args, xlo, xhi)
            count_absent(name, frames, tree_map, drive, args, totals)
        chain_absent(
            name,
            tree_map,
            partial(simulate_drive_x, xy, dbh, xlo=xlo, xhi=xhi, whole_path=True),
            args,
        )
    whole = build_map(xy)
    for frames in (1, 5):
        drive = partial(simulate_drive, ll_xy, ll_dbh, rng, frames, args)
        count_absent("longleaf in clustered", frames, whole, drive, args, totals)
    chain_absent("longleaf in clustered", whole, partial(simulate_drive, ll_xy, ll_dbh), args)


def run_stand_absent(args, name: str, totals) -> None:
    """Absent places of another `--stand` (e.g. bei): its halves (own random stream)."""
    from forestslam.localization import build_map

    rng = np.random.default_rng(args.seed + 140)
    label, xy, dbh = stand_by_name(name)
    has_dbh = bool(np.isfinite(dbh).any())
    short = Path(label).stem if Path(name).is_file() else name
    for case, (in_map, (xlo, xhi)) in halves(short, xy, args).items():
        tree_map = build_map(xy[in_map], dbh[in_map] if has_dbh else None)
        for frames in (1, 5):
            drive = partial(simulate_drive_x, xy, dbh, rng, frames, args, xlo, xhi)
            count_absent(case, frames, tree_map, drive, args, totals)
        chain_absent(
            case,
            tree_map,
            partial(simulate_drive_x, xy, dbh, xlo=xlo, xhi=xhi, whole_path=True),
            args,
        )


def simulate_drive_x(xy, dbh, rng, frames, args, xlo, xhi, whole_path=False) -> Drive:
    """simulate_drive with the last pose's x inside [xlo, xhi] (a strip of the stand); with
    `whole_path` every frame's (a long drive's earlier frames would otherwise see into the
    mapped half: the chain's 7-frame drives, 18 m, were found there, 0.1 m off, and counted as
    absent places accepted)."""
    ylo, yhi = float(xy[:, 1].min()) + 5, float(xy[:, 1].max()) - 5
    for _ in range(1000):
        d = simulate_drive(xy, dbh, rng, frames, args, min(xlo, ylo), max(xhi, yhi))
        at = np.array([T[:2, 3] for T in d.poses]) if whole_path else np.array([d.truth[:2]])
        if ((at >= [xlo, ylo]) & (at <= [xhi, yhi])).all():
            return d
    raise RuntimeError("no drivable pose in the strip")


# TreeLoc++'s Venman (Wild-Places V) test regions (its evaluation code, WildVTestPolygons):
# inter-session queries are the query frames inside these polygons with a map frame within 5 m.
VENMAN_TEST_POLYGONS = [
    [
        (-468.0, -82.0),
        (-468.0, 44.0),
        (-314.0, 44.0),
        (-305.0, 12.0),
        (-192.0, 44.0),
        (-192.0, -82.0),
    ],
    [(-78.0, -171.0), (-78.0, -215.0), (-305.0, -215.0), (-305.0, -171.0)],
    [(-62.0, 70.0), (95.0, 70.0), (142.0, 0.0), (140.0, -142.0), (-62.0, -142.0)],
]


def in_polygons(xy: np.ndarray, polygons) -> np.ndarray:
    from matplotlib.path import Path as MplPath

    inside = np.zeros(len(xy), bool)
    for poly in polygons:
        inside |= MplPath(np.array(poly)).contains_points(xy)
    return inside


def treeloc_retry_view(table, k: int, args, config):
    """The query of frame k retried as `forestslam localize --retry-frames R` would: frame k
    and up to R - 1 earlier frames at least config.retry_keyframe_distance_m apart, each
    levelled by its stems, aggregated in frame k's levelled frame by the table's reference
    poses (standing in for odometry: no drift); with the frames each trunk was seen in."""
    from forestslam.geometry import planar_pose
    from forestslam.localization import aggregate_stems
    from forestslam.localization.tables import query_trees, true_planar_pose

    frames = [int(f) for f in table.frames if f <= k][::-1]  # k first, then earlier
    chosen, last = [], None
    for j in frames:
        pos = table.poses[j][:2, 3]
        if last is None or np.linalg.norm(pos - last) >= config.retry_keyframe_distance_m:
            chosen.append(j)
            last = pos
        if len(chosen) >= args.treeloc_retry:
            break
    xys, poses = [], []
    for j in chosen[::-1]:
        xy, _dbh, R = query_trees(table, j, args.treeloc_gravity, config.max_range_m)
        xys.append(xy)
        poses.append(planar_pose(*true_planar_pose(table, j, R)))
    return aggregate_stems(xys, poses, config, return_observations=True)


def treeloc_localize(tree_map, table, k: int, args, config):
    """(answer, levelling of frame k, trunks, retried) of frame k's query; retried on more
    frames when rejected and --treeloc-retry asks for it."""
    from forestslam.localization import localize
    from forestslam.localization.tables import query_trees

    local, local_dbh, R = query_trees(table, int(k), args.treeloc_gravity, config.max_range_m)
    loc = localize(tree_map, local, config, local_dbh if args.treeloc_dbh else None)
    if loc.rejected and args.treeloc_retry > 1:
        local, seen_in = treeloc_retry_view(table, int(k), args, config)
        return localize(tree_map, local, config, observations=seen_in), R, len(local), True
    return loc, R, len(local), False


def run_treeloc(args) -> None:
    """Wild-Places Venman V03/V04 tree tables (RealtimeTrees, as shipped with TreeLoc++): each
    session's frames as queries in a map built from the other session's frames."""
    from scipy.spatial import cKDTree

    from forestslam.io.tree_tables import read_tree_table
    from forestslam.localization import LocalizationConfig, build_map
    from forestslam.localization.tables import table_map_xy, true_planar_pose

    root = DATA / "treeloc"
    if not (root / "wild_v03").is_dir():
        print("\n== TreeLoc tables: skipped (../shared/data/treeloc absent) ==")
        return
    tables = {name: read_tree_table(root / f"wild_{name}") for name in ("v03", "v04")}
    print("\n== Wild-Places Venman tree tables (RealtimeTrees): inter-session localization ==")
    print(
        "protocol (TreeLoc++ inter): query frames inside its Venman test polygons with a map "
        "frame within 5 m; success = within 0.5 m and 5 deg of the reference pose of the "
        f"query frame; queries levelled by their stem axes ({args.treeloc_gravity}); "
        "absent = query frames farther than the query range + 1 m from every map tree (no "
        "query tree can have its tree in the map), in the whole map and in the map's western "
        "half (V04 lies inside V03's coverage)"
    )
    config = LocalizationConfig()
    if args.treeloc_range is not None:
        config.max_range_m = args.treeloc_range
    print(
        f"query trees within {config.max_range_m:.0f} m of the frame's pose; DBH evidence "
        f"{'on (the tables DBH, both sides)' if args.treeloc_dbh else 'off (positions only)'}"
    )
    for q_name, m_name in (("v03", "v04"), ("v04", "v03")):
        qt, mt = tables[q_name], tables[m_name]
        c0 = time.process_time()
        map_xy, map_dbh = table_map_xy(mt)
        tree_map = build_map(map_xy, map_dbh)
        build_s = time.process_time() - c0
        q_pos = qt.poses[:, :2, 3]
        m_pos = mt.poses[:, :2, 3]
        near_map = cKDTree(m_pos).query(q_pos)[0]
        frames = qt.frames
        test = frames[in_polygons(q_pos[frames], VENMAN_TEST_POLYGONS) & (near_map[frames] <= 5.0)]
        reach = config.max_range_m + 1.0
        absent = frames[cKDTree(map_xy).query(q_pos[frames])[0] > reach]
        rows = []
        for kind, ks in (("test", test), ("absent", absent)):
            for k in ks:
                c0 = time.process_time()
                loc, R, n_local, retried = treeloc_localize(tree_map, qt, int(k), args, config)
                ms = 1e3 * (time.process_time() - c0)
                tx, ty, tyaw = true_planar_pose(qt, int(k), R)
                rows.append(
                    (
                        kind,
                        loc.accepted,
                        loc.x - tx,
                        loc.y - ty,
                        math.remainder(loc.yaw - tyaw, 2 * math.pi),
                        ms,
                        n_local,
                        loc.stage,
                        retried,
                    )
                )
        test_rows = [r for r in rows if r[0] == "test"]
        acc = [r for r in test_rows if r[1]]
        n = len(test_rows)
        e = np.array([[r[2], r[3], r[4]] for r in acc]).reshape(-1, 3)
        raw = np.hypot(e[:, 0], e[:, 1])
        ok_raw = (raw <= 0.5) & (np.degrees(np.abs(e[:, 2])) <= 5)
        offset = np.median(e, axis=0) if len(e) else np.zeros(3)
        r = e - offset
        res = np.hypot(r[:, 0], r[:, 1])
        ok = (res <= 0.5) & (np.degrees(np.abs(r[:, 2])) <= 5)
        far = res > 5.0
        absent_rows = [r for r in rows if r[0] == "absent"]
        absent_acc = sum(r[1] for r in absent_rows)
        ms = np.array([r[5] for r in rows])
        print(
            f"\n{q_name.upper()} queries in a {m_name.upper()} map ({len(map_xy)} trees, built in "
            f"{build_s:.1f} s CPU): {n} test queries "
            f"(median {np.median([r[6] for r in test_rows]):.0f} trees)"
        )
        print(
            f"  accepted {len(acc)}/{n} = {len(acc) / max(n, 1):.1%}, "
            f"triangle stage {sum(r[7] == 'triangle' for r in acc)}; retried "
            f"{sum(r[8] for r in test_rows)} (on up to {args.treeloc_retry} frames), accepted "
            f"on the retry {sum(r[8] for r in acc)}"
        )
        print(
            f"  within 0.5 m / 5 deg of the reference: {ok_raw.sum()}/{n} = "
            f"{ok_raw.sum() / max(n, 1):.1%}"
        )
        print(
            f"  sessions' constant offset (median error): dx {offset[0]:+.2f} m, "
            f"dy {offset[1]:+.2f} m, "
            f"dyaw {math.degrees(offset[2]):+.2f} deg"
        )
        print(
            f"  after removing it: within 0.5 m / 5 deg {ok.sum()}/{n} = "
            f"{ok.sum() / max(n, 1):.1%}; "
            f"error median {np.median(res) if len(res) else float('nan'):.3f} m, "
            f"p90 {np.percentile(res, 90) if len(res) else float('nan'):.3f} m; "
            f"wrongly accepted (> 0.5 m or 5 deg) {(~ok).sum()}, of them > 5 m off {far.sum()}"
        )
        print(
            f"  absent places (query > {reach:.0f} m from every map tree): accepted "
            f"{absent_acc}/{len(absent_rows)}"
            f" = {absent_acc / max(len(absent_rows), 1):.2%} (target <= 0.5 %)"
        )
        ms_test = np.array([r[5] for r in test_rows])
        ms_absent = np.array([r[5] for r in absent_rows]) if absent_rows else np.zeros(1)
        print(
            f"  CPU per query: test median {np.median(ms_test):.2f} ms, p95 "
            f"{np.percentile(ms_test, 95):.2f} ms; absent median {np.median(ms_absent):.2f} ms, "
            f"p95 {np.percentile(ms_absent, 95):.2f} ms"
        )
        west = map_xy[:, 0] < np.median(map_xy[:, 0])
        half = build_map(map_xy[west], map_dbh[west])
        away = frames[cKDTree(map_xy[west]).query(q_pos[frames])[0] > reach]
        half_acc = 0
        for k in away:
            half_acc += treeloc_localize(half, qt, int(k), args, config)[0].accepted
        print(
            f"  absent places in the map's western half ({west.sum()} trees; queries > "
            f"{reach:.0f} m from all of them): accepted {half_acc}/{len(away)} = "
            f"{half_acc / max(len(away), 1):.2%} (target <= 0.5 %)"
        )
        if q_name == "v03":
            print(
                "  TreeLoc++ (paper / its repository, same 543 V03 queries): Recall@1 0.92; "
                "34.4 % within 0.5 m / 5 deg"
            )


LI_TABLE_I = {
    1: (54, 1.71, 0.229),
    3: (123, 4.97, 0.888),
    5: (140, 10.2, 0.993),
    10: (134, 14.4, 1.0),
}


def run_paper_table(args) -> None:
    """Li et al.'s Table I (aggregated frames -> trunks, matched triangles, success) for both
    matchers on simulated views of the longleaf stand, beside the paper's rows (Lieksa harvester
    data, trunks extracted from aggregated clouds: not the same data, so compare trends)."""
    from forestslam.localization import LocalizationConfig, build_map, localize

    xy, dbh = load_stand(DATA / "stands" / "longleaf.csv")
    tree_map = build_map(xy, dbh)
    args.range = args.ranges[0]
    args.dbh_rng = np.random.default_rng(args.seed + 250)
    print("\n== Li et al. Table I: aggregated frames (simulated views, longleaf map) ==")
    print(
        f"{'frames':>6} | {'paper: trunks':>13} {'matched tri':>11} {'success':>7} | "
        f"{'matcher':>8} {'trunks':>6} {'matched tri':>11} {'success':>7} {'wrong':>5} "
        f"{'ms':>5}"
    )
    for frames in (1, 3, 5, 10):
        rng = np.random.default_rng(args.seed + 1000 + frames)
        queries = [simulate_query(xy, dbh, rng, frames, args) for _ in range(args.paper_queries)]
        for matcher in ("paper", "default"):
            config = LocalizationConfig(matcher=matcher)
            tri, ok, wrong, ms = [], 0, 0, []
            for local, truth, _dbh, seen_in in queries:
                c0 = time.process_time()
                loc = localize(tree_map, local, config, observations=seen_in)
                ms.append(1e3 * (time.process_time() - c0))
                tri.append(loc.matched_triangles)
                if loc.accepted:
                    e, d = pose_error(loc, truth)
                    ok += e < 0.5 and d < 2
                    wrong += not (e < 0.5 and d < 2)
            n = len(queries)
            paper = LI_TABLE_I[frames]
            left = (
                f"{frames:>6} | {paper[0]:>13} {paper[1]:>11.2f} {paper[2]:>7.1%} |"
                if matcher == "paper"
                else f"{'':>6} | {'':>13} {'':>11} {'':>7} |"
            )
            print(
                f"{left} {matcher:>8} {np.mean([len(q[0]) for q in queries]):>6.1f} "
                f"{np.mean(tri):>11.2f} {ok / n:>7.1%} {wrong:>5} {np.mean(ms):>5.2f}"
            )


def run_fortls() -> None:
    from forestslam.io import read_trees_csv
    from forestslam.localization import build_map, localize

    field_path, tls_path = DATA / "fortls" / "field_trees.csv", DATA / "fortls" / "tls_trees.csv"
    if not field_path.is_file():
        print("\n== FORTLS: skipped (../shared/data/fortls absent) ==")
        return
    field, tls = read_trees_csv(field_path), read_trees_csv(tls_path)
    plots = sorted(set(field["plot"].astype(int)))
    spacing = 100.0  # plots are 20 m radius; place them 100 m apart along x
    offsets = {p: np.array([spacing * k, 0.0]) for k, p in enumerate(plots)}
    map_xy = np.vstack(
        [np.column_stack([field["x"], field["y"]])[field["plot"] == p] + offsets[p] for p in plots]
    )
    map_dbh = np.concatenate([field["dbh_cm"][field["plot"] == p] / 100 for p in plots])
    tree_map = build_map(map_xy, map_dbh)
    print(f"\n== FORTLS: TLS trees of each plot in one map of {len(plots)} field plots ==")
    print(f"global map: {tree_map}, plot p centred at ({spacing:.0f}*(p-1), 0)")
    print(
        f"{'plot':>4} {'field':>5} {'tls':>4} {'found':>6} {'plot hit':>8} {'inliers':>7} "
        f"{'rot deg':>8} {'dx m':>7} {'dy m':>7} {'rms m':>6} {'ms':>6}"
    )
    correct = correct_dbh = 0
    for p in plots:
        local = np.column_stack([tls["x"], tls["y"]])[tls["plot"] == p]
        local_dbh = tls["dbh_cm"][tls["plot"] == p] / 100
        with_dbh = localize(tree_map, local, local_dbh_m=local_dbh)
        correct_dbh += with_dbh.accepted and np.hypot(with_dbh.x - offsets[p][0], with_dbh.y) < 5
        loc = localize(tree_map, local)
        # Which plot did the local centre land in?
        hit = int(np.argmin([np.hypot(loc.x - o[0], loc.y - o[1]) for o in offsets.values()]))
        hit_plot = plots[hit]
        right = (not loc.rejected) and hit_plot == p
        correct += right
        off = np.array([loc.x, loc.y]) - offsets[p]
        print(
            f"{p:>4} {int((field['plot'] == p).sum()):>5} {len(local):>4} "
            f"{'yes' if not loc.rejected else 'REJ':>6} {'right' if right else 'WRONG':>8} "
            f"{loc.inliers:>7} {math.degrees(loc.yaw):>8.2f} {off[0]:>7.2f} {off[1]:>7.2f} "
            f"{loc.rms_m:>6.3f} {loc.time_ms:>6.2f} {loc.stage or '-':>8} "
            f"{loc.significance:>6.1f}"
        )
    print(
        f"right plot found for {correct}/{len(plots)} plots, with the TLS and field DBH "
        f"{correct_dbh}/{len(plots)} (target: all)"
    )
    run_fortls_leave_one_out(field, tls, plots)


def fortls_layout(field: dict, plots: list[int]) -> dict[int, np.ndarray]:
    """Centres of the field plots in one frame. The plots overlap on the ground (neighbours
    about 20 m apart share trees: identical positions and DBH), so each plot is localized in
    its neighbours' field trees (exact, rms ~0) and the offsets are chained from plot 1."""
    from forestslam.localization import build_map, localize

    xy = {p: np.column_stack([field["x"], field["y"]])[field["plot"] == p] for p in plots}
    centres = {plots[0]: np.zeros(2)}
    todo = [plots[0]]
    while todo:
        q = todo.pop()
        tree_map = build_map(xy[q])
        for p in plots:
            if p in centres:
                continue
            loc = localize(tree_map, xy[p])
            if loc.accepted and loc.rms_m < 0.01 and abs(loc.yaw) < 1e-3:
                centres[p] = centres[q] + [loc.x, loc.y]
                todo.append(p)
    return centres


def run_fortls_leave_one_out(field: dict, tls: dict, plots: list[int]) -> None:
    """Absent places on real trees: the FORTLS stand rebuilt from its overlapping plots, minus
    everything within 25 m of the queried plot's centre (the plot and the neighbours' trees
    that are the same trees); the plot's TLS trees are queried in the rest. Accepted = wrong.
    (Placing the plots 100 m apart and leaving one out does not remove the place: about half
    of its trees are in its neighbours, where those queries are rightly found.)"""
    from forestslam.localization import build_map, localize

    centres = fortls_layout(field, plots)
    if len(centres) < len(plots):
        print(f"FORTLS layout: only {len(centres)} of {len(plots)} plots chained; LOPO skipped")
        return
    stand = np.vstack(
        [np.column_stack([field["x"], field["y"]])[field["plot"] == p] + centres[p] for p in plots]
    )
    stand_dbh = np.concatenate([field["dbh_cm"][field["plot"] == p] / 100 for p in plots])
    from forestslam.localization import merge_close

    # The same tree measured in two plots is one (same position and DBH).
    stand, labels = merge_close(stand, 0.05, return_labels=True)
    stand_dbh = np.bincount(labels, stand_dbh) / np.bincount(labels)
    tls_xy = {p: np.column_stack([tls["x"], tls["y"]])[tls["plot"] == p] for p in plots}
    tls_dbh = {p: tls["dbh_cm"][tls["plot"] == p] / 100 for p in plots}
    print(f"\nFORTLS stand rebuilt from the overlapping plots: {len(stand)} distinct trees")
    # Present: each plot's TLS trees in the whole stand (right within 3 m of its centre).
    tree_map = build_map(stand, stand_dbh)
    right = right_dbh = 0
    for p in plots:
        for dbh in (None, tls_dbh[p]):
            loc = localize(tree_map, tls_xy[p], local_dbh_m=dbh)
            hit = loc.accepted and float(np.hypot(*(np.array([loc.x, loc.y]) - centres[p]))) < 3
            right += hit and dbh is None
            right_dbh += hit and dbh is not None
    print(
        f"present: TLS plot found in the whole stand {right}/{len(plots)}, with DBH "
        f"{right_dbh}/{len(plots)}"
    )
    print("leave-one-plot-out (map: stand minus 25 m around the plot; accepted = wrong)")
    print(
        f"{'plot':>4} {'map':>4} {'accepted':>8} {'stage':>8} {'inliers':>7} {'signif':>7} "
        f"{'w/ dbh':>6} {'signif':>6} reason"
    )
    wrong = wrong_dbh = 0
    for p in plots:
        keep = np.hypot(*(stand - centres[p]).T) > 25.0
        left_out = build_map(stand[keep], stand_dbh[keep])
        loc = localize(left_out, tls_xy[p])
        loc_dbh = localize(left_out, tls_xy[p], local_dbh_m=tls_dbh[p])
        wrong += loc.accepted
        wrong_dbh += loc_dbh.accepted
        print(
            f"{p:>4} {int(keep.sum()):>4} {'YES' if loc.accepted else 'no':>8} "
            f"{loc.stage or '-':>8} {loc.inliers:>7} {loc.significance:>7.2f} "
            f"{'YES' if loc_dbh.accepted else 'no':>6} {loc_dbh.significance:>6.2f} {loc.reason}"
        )
    print(
        f"absent plot accepted {wrong}/{len(plots)}, with DBH {wrong_dbh}/{len(plots)} "
        "(target <= 0.5 %)"
    )
    # Ten queries cannot show a rate of 0.5 %: each left-out plot is also queried with 20 random
    # partial views (80 % of its TLS trees, another scan position's misses), 200 queries.
    rng = np.random.default_rng(16)
    subsets = accepted = accepted_dbh = 0
    for p in plots:
        keep = np.hypot(*(stand - centres[p]).T) > 25.0
        tree_map = build_map(stand[keep], stand_dbh[keep])
        for _ in range(20):
            part = rng.uniform(size=len(tls_xy[p])) < 0.8
            accepted += localize(tree_map, tls_xy[p][part]).accepted
            accepted_dbh += localize(
                tree_map, tls_xy[p][part], local_dbh_m=tls_dbh[p][part]
            ).accepted
            subsets += 1
    print(
        f"absent plot, partial views (80 % of the TLS trees, 20 per plot): accepted "
        f"{accepted}/{subsets} = {accepted / subsets:.2%}, with DBH {accepted_dbh}/{subsets} "
        f"= {accepted_dbh / subsets:.2%} (target <= 0.5 %)"
    )


def sequence_errors(out_dir: Path, truth_dir: Path) -> tuple[int, int, list, list, int]:
    """Queries, accepted, position errors (m) and yaw errors (deg) of accepted queries, and
    how many accepted queries were wrong (>= 0.5 m or >= 2 deg), against the truth trajectory."""
    import json

    from forestslam.io import read_tum

    doc = json.loads((out_dir / "localization.json").read_text())
    ts, tp = read_tum(truth_dir / "trajectory.tum")
    errs, degs, wrong = [], [], 0
    for q in doc["queries"]:
        if not q["accepted"]:
            continue
        j = int(np.argmin(np.abs(ts - q["stamp"])))
        e = math.hypot(q["x"] - tp[j][0, 3], q["y"] - tp[j][1, 3])
        d = abs(
            math.degrees(
                math.remainder(q["yaw"] - math.atan2(tp[j][1, 0], tp[j][0, 0]), 2 * math.pi)
            )
        )
        errs.append(e)
        degs.append(d)
        wrong += not (e < 0.5 and d < 2.0)
    return len(doc["queries"]), doc["accepted"], errs, degs, wrong


def run_sequences(args) -> None:
    """Real detections (perception, odometry) on simulated sequences, via the CLI runner."""
    from forestslam.localization import load_map
    from forestslam.localization.runner import run_localization

    print("\n== Simulated sequences: real detections (forestslam.perception + odometry) ==")
    print(
        f"{'sequence':>12} {'frames':>6} {'keyframe m':>10} {'queries':>7} {'success':>8} "
        f"{'wrong acc':>9} {'median err m':>12} {'median deg':>10} {'ms/query':>8}"
    )
    for seq in args.sequences:
        seq = Path(seq)
        if not (seq / "truth" / "trees.csv").is_file():
            print(f"{seq}: no simulator output (truth/trees.csv) - skipped")
            continue
        tree_map = load_map(seq / "truth" / "trees.csv")
        bag = next(p for p in seq.iterdir() if p.name.startswith("sequence."))
        # 1 frame; 5 frames; 1 frame retried on up to 5 when rejected (--retry-frames 5)
        for frames, keyframe, retry in ((1, 0.0, 0), (5, 1.0, 0), (1, 1.0, 5)):
            label = f"{frames}>{retry}" if retry else str(frames)
            out = Path(args.work_dir) / f"{seq.name}-{label}"
            run = run_localization(
                bag,
                tree_map,
                "vlp16",
                out,
                frames=frames,
                every=args.every,
                keyframe_distance_m=keyframe,
                retry_frames=retry,
                overwrite=True,
            )
            n, acc, errs, degs, wrong = sequence_errors(out, seq / "truth")
            ok = len(errs) - wrong
            print(
                f"{seq.name:>12} {label:>6} {keyframe:>10.1f} {n:>7} {ok / max(n, 1):>8.1%} "
                f"{wrong / max(n, 1):>9.1%} {np.median(errs) if errs else float('nan'):>12.3f} "
                f"{np.median(degs) if degs else float('nan'):>10.2f} {run.median_query_ms:>8.2f}"
            )


def random_stand(n: int, density: float, rng: np.random.Generator) -> np.ndarray:
    side = math.sqrt(n / density)
    xy = rng.uniform(0, side, (int(n * 1.3), 2))
    from scipy.spatial import cKDTree

    # Thin pairs closer than 1 m (a forest has a minimum stem spacing).
    pairs = cKDTree(xy).query_pairs(1.0, output_type="ndarray")
    keep = np.ones(len(xy), bool)
    keep[pairs[:, 1]] = False
    return xy[keep][:n]


def run_speed(args) -> None:
    from forestslam.localization import build_map

    rng = np.random.default_rng(args.seed)
    print("\n== Speed (one core) ==")
    for n in (2000, 10000):
        xy = random_stand(n, 0.02, rng)
        t0, c0 = time.perf_counter(), time.process_time()
        tree_map = build_map(xy)
        build_s, cpu_s = time.perf_counter() - t0, time.process_time() - c0
        print(
            f"map build {len(xy)} trees: {build_s * 1e3:.1f} ms wall, {cpu_s * 1e3:.1f} ms CPU "
            f"({tree_map})"
        )
    for n_map in (2000, 20000):
        xy = random_stand(n_map, 0.02, rng)
        run_speed_queries(args, rng, xy)


def run_speed_queries(args, rng, xy) -> None:
    from forestslam.localization import build_map, localize

    dbh = np.full(len(xy), 0.3)
    tree_map = build_map(xy, dbh)
    for frames in (1, 5):
        times, cpu, sizes, ok = [], [], [], 0
        lo, hi = float(xy.min() + 5), float(xy.max() - 5)
        for _ in range(args.speed_queries):
            local, truth, _dbh, seen_in = simulate_query(xy, dbh, rng, frames, args, lo, hi)
            c0 = time.process_time()
            loc = localize(tree_map, local, observations=seen_in)
            cpu.append(1e3 * (time.process_time() - c0))
            sizes.append(len(local))
            times.append(loc.time_ms)
            e, d = pose_error(loc, truth)
            ok += (not loc.rejected) and e < 0.5 and d < 2
        t = np.array(times)
        print(
            f"query vs {len(xy):,}-tree map, {frames} frame(s), median {np.median(sizes):.0f} "
            f"trunks: "
            f"wall median {np.median(t):.2f} ms, p95 {np.percentile(t, 95):.2f} ms, "
            f"max {t.max():.2f} ms; CPU mean {np.mean(cpu):.2f} ms, p95 "
            f"{np.percentile(cpu, 95):.2f} ms (success {ok}/{len(t)}; target <= 10 ms)"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=1000)
    parser.add_argument("--absent-queries", type=int, default=200, help="per absent-place case")
    parser.add_argument("--paper-queries", type=int, default=300, help="per row of Table I")
    parser.add_argument("--speed-queries", type=int, default=200)
    parser.add_argument(
        "--ranges", type=lambda v: [float(x) for x in v.split(",")], default=[20.0, 18.0, 15.0]
    )
    parser.add_argument(
        "--frames",
        type=lambda v: sorted({int(x) for x in v.split(",")}),
        default=[1, 5],
        help="frames per simulated query (comma list); the most also gives the retry row",
    )
    parser.add_argument("--range", type=float, default=20.0, help="for the speed part")
    parser.add_argument("--dropout", type=float, default=0.15)
    parser.add_argument("--sapling-dropout", type=float, default=0.5)
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument("--false-trunks", type=float, default=2.0, help="persistent, per query")
    parser.add_argument("--transient-false", type=float, default=1.0, help="per frame")
    parser.add_argument("--spacing", type=float, default=3.0, help="metres between frames")
    parser.add_argument(
        "--chain",
        type=lambda v: [int(x) for x in v.split(",")],
        default=[1, 5, 7],
        help="'keep driving until accepted': frames of each look, increasing, starting at 1 "
        "(frames --spacing m apart: 1,5,7 = 0, 12, 18 m driven); fewer than 3 looks: off",
    )
    parser.add_argument("--min-observations", type=int, default=1)
    parser.add_argument("--dbh-noise", type=float, default=0.03, help="query DBH sigma, m")
    parser.add_argument("--dbh-outliers", type=float, default=0.1, help="gross DBH errors")
    parser.add_argument("--dbh-missing", type=float, default=0.2, help="DBH not measured")
    parser.add_argument(
        "--margin", type=float, default=20.0, help="poses this far inside the stand"
    )
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--poses",
        type=lambda v: [x for x in v.split(",") if x],
        default=["uniform", "working"],
        help="query pose models of the 'sim' part (comma list of uniform, working)",
    )
    parser.add_argument(
        "--reach",
        type=lambda v: tuple(float(x) for x in v.split(",")),
        default=(2.0, 8.0),
        help="'working' poses: min,max metres from the worked tree (crane reach)",
    )
    parser.add_argument(
        "--stand",
        action="append",
        default=None,
        help="stand of the 'sim' part (repeatable): a shared stand (longleaf, spruces), "
        "'clustered' (seeded bei-density stand) or a CSV x,y[,dbh_m]; default longleaf and "
        "clustered",
    )
    parser.add_argument(
        "--treeloc-gravity",
        choices=["stems", "reference", "none"],
        default="stems",
        help="levelling of the tree-table queries",
    )
    parser.add_argument(
        "--treeloc-dbh", action="store_true", help="pass the query trees' DBH (tree tables)"
    )
    parser.add_argument(
        "--treeloc-range", type=float, default=None, help="query range (default: the config's)"
    )
    parser.add_argument(
        "--treeloc-retry",
        type=int,
        default=0,
        help="retry a rejected tree-table query on up to this many frames (0: no retry)",
    )
    parser.add_argument(
        "--sequences",
        nargs="*",
        default=[],
        help="simulator output dirs (forestslam simulate --out DIR) to localize along",
    )
    parser.add_argument("--every", type=int, default=10, help="query every K scans (sequences)")
    parser.add_argument("--work-dir", default="/tmp/localize_bench")
    parser.add_argument(
        "--only",
        choices=["sim", "absent", "fortls", "speed", "seq", "treeloc", "paper"],
        default=None,
    )
    args = parser.parse_args()
    args.stand = args.stand or ["longleaf", "clustered"]
    if not args.poses or set(args.poses) - {"uniform", "working"}:
        parser.error(f"--poses: a comma list of uniform, working; got {args.poses}")
    args.dbh_rng = np.random.default_rng(args.seed + 350)
    if not (DATA / "stands" / "longleaf.csv").is_file():
        print("../shared/data absent: nothing to benchmark", file=sys.stderr)
        return 1
    if args.only in (None, "sim"):
        run_simulated(args)
    if args.only in (None, "sim", "absent"):
        run_simulated_absent(args)
    if args.only in (None, "fortls"):
        run_fortls()
    if args.only in (None, "treeloc"):
        run_treeloc(args)
    if args.only in (None, "paper"):
        run_paper_table(args)
    if args.only in (None, "speed"):
        run_speed(args)
    if args.only in (None, "seq") and args.sequences:
        run_sequences(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
