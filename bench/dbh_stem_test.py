"""The tree map's stem-or-not test (TreeMap.is_stem), before/after on recorded runs.

  python bench/dbh_pose_replay.py record BAG --sensor vlp16 --out RUN [other `run` options]
  forestslam evaluate RUN --truth TRUTH
  python bench/dbh_stem_test.py RUN TRUTH [RUN TRUTH ...]

Replays each run's recorded tree-map calls (same scans, poses and associations) twice: with
round 1's rule (before the test; checked equal to a run's own trees.csv when the run was made
before the test) and with the test. Prints per run: mapped trees,
trees passing the test, the share of mapped trees and of stems with a DBH, and every tree
whose DBH the test removed with the truth it matches (truth DBH, or "no tree" when it matches
no truth stem). Then bias, MAE, the share within +-1 sigma and the share with a DBH on the
trees `forestslam evaluate` scores (truth DBH >= 10 cm, within 15 m of the path), both ways.
Tree positions are the same both ways (the test only decides the DBH), so tree recall and
precision are those `forestslam evaluate` printed for the run.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from dbh_pose_replay import replay  # noqa: E402

from forestslam.evaluation.trees import tree_errors  # noqa: E402
from forestslam.io import read_trees_csv, read_tum  # noqa: E402
from forestslam.mapping import tree_map as tm  # noqa: E402


def round1_rule(self, tree) -> bool:
    """Before the test (h4-dbh round 1): a window DBH when a window agrees with the scans'
    width (TreeMap.dbh), else the per-scan fallback when perception had a DBH in at least half
    of the tree's scans."""
    scans = np.asarray(tree.scan_dbh)
    windows = np.array([d for d, _ in tree.measurements])
    if len(windows) and len(scans) < self.cfg.dbh_fallback_min_scans:
        return True
    if (windows <= self.cfg.dbh_max_scan_ratio * np.median(scans)).any():
        return True
    return 2 * tree.n_scans_dbh >= tree.n_scans


def replayed_table(run: Path, before: bool) -> tuple[dict, np.ndarray]:
    """trees.csv columns of the run's trees from a replay, and which trees pass the test."""
    is_stem = tm.TreeMap.is_stem
    if before:
        tm.TreeMap.is_stem = round1_rule
    est = read_trees_csv(run / "trees.csv")
    ids = est["id"].astype(np.int64) - 1  # trees.csv ids are landmarks + 1
    try:
        trees = replay(run, None, {})
        table = trees.table(ids, np.c_[est["x"], est["y"]], est["observations"])
    finally:
        tm.TreeMap.is_stem = is_stem
    stem = np.array([i in trees.trees and is_stem(trees, trees.trees[i]) for i in ids])
    return table | {"x": est["x"], "y": est["y"], "z": est["z"]}, stem


def matches(run: Path, truth: Path, table: dict) -> tuple[np.ndarray, np.ndarray, dict]:
    """Truth row of each mapped tree (-1 none), which of those are scored, and the truth."""
    metrics = json.loads((run / "metrics.json").read_text())
    alignment = np.asarray(metrics["trajectory"]["alignment"])
    tru = read_trees_csv(truth / "trees.csv")
    _, poses = read_tum(truth / "trajectory.tum")
    tru_xy = np.c_[tru["x"], tru["y"]]
    est_xyz = np.c_[table["x"], table["y"], np.nan_to_num(table["z"])]
    r = tree_errors(est_xyz, table["dbh_m"], tru_xy, tru["dbh_m"], poses[:, :2, 3], alignment)
    m = r["match_est_to_truth"]
    near = np.hypot(*(tru_xy[:, None, :] - poses[None, :, :2, 3]).transpose(2, 0, 1)).min(1)
    scored_truth = (tru["dbh_m"] >= 0.1) & (near <= 15)
    scored = np.zeros(len(m), dtype=bool)
    scored[m >= 0] = scored_truth[m[m >= 0]]
    return m, scored, tru


def scored_figures(table: dict, m: np.ndarray, scored: np.ndarray, tru: dict) -> str:
    e = 100 * (table["dbh_m"][scored] - tru["dbh_m"][m[scored]])
    sd = 100 * table["dbh_std_m"][scored]
    ok = np.isfinite(e)
    within = np.mean(np.abs(e[ok]) <= sd[ok])
    return (
        f"bias {e[ok].mean():+.2f} MAE {np.abs(e[ok]).mean():.2f} within 1 sigma {within:.2f} "
        f"with DBH {ok.mean():.2f} ({ok.sum()}/{len(e)})"
    )


def classes(table: dict, m: np.ndarray, tru: dict) -> str:
    """Mapped trees with a DBH / all, by the truth they match: a tree of DBH >= 10 cm, a
    sapling under 10 cm, no truth tree (clutter, a shrub)."""
    truth_cm = np.full(len(m), np.nan)
    truth_cm[m >= 0] = 100 * tru["dbh_m"][m[m >= 0]]
    has = np.isfinite(table["dbh_m"])
    kinds = {"tree >= 10 cm": truth_cm >= 10, "sapling < 10 cm": truth_cm < 10}
    kinds["no tree"] = m < 0
    return ", ".join(f"{name} {has[k].sum()}/{k.sum()}" for name, k in kinds.items())


def main(argv: list[str]) -> None:
    for run, truth in zip(argv[::2], argv[1::2], strict=True):
        run, truth = Path(run), Path(truth)
        before, _ = replayed_table(run, before=True)
        after, stem = replayed_table(run, before=False)
        m, scored, tru = matches(run, truth, after)
        has_b, has_a = np.isfinite(before["dbh_m"]), np.isfinite(after["dbh_m"])
        recorded = read_trees_csv(run / "trees.csv")["dbh_m"]
        same = np.array_equal(np.isnan(recorded), ~has_b) and np.allclose(
            recorded[has_b], before["dbh_m"][has_b], atol=1e-6
        )
        print(
            f"{run}: mapped {len(stem)}, stems {stem.sum()}; with DBH of mapped "
            f"{has_b.mean():.2f} -> {has_a.mean():.2f}, of stems {has_a[stem].mean():.2f}; "
            f"before = the run's own trees.csv: {same}"
        )
        for j in np.nonzero(has_b & ~has_a)[0]:
            what = f"truth DBH {100 * tru['dbh_m'][m[j]]:.1f} cm" if m[j] >= 0 else "no tree"
            tree, dbh_cm = int(after["id"][j]) + 1, 100 * before["dbh_m"][j]
            print(f"  DBH removed: tree {tree} {dbh_cm:.1f} cm, {what}")
        print(f"  with a DBH after / mapped, by what the tree matches: {classes(after, m, tru)}")
        print(f"  scored before: {scored_figures(before, m, scored, tru)}")
        print(f"  scored after:  {scored_figures(after, m, scored, tru)}")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1:])
