"""How much of the map DBH error is pose error? Record the tree map's inputs during a
`forestslam run`, then replay them with the SLAM poses and with the simulator's true poses
(same scans, stems, associations and windows) and score both against the truth; optionally a
third replay with MappingConfig overrides (a candidate change), with SLAM and true poses.

  python bench/dbh_pose_replay.py record BAG --sensor vlp16 --out RUN [other `run` options]
  forestslam evaluate RUN --truth TRUTH
  python bench/dbh_pose_replay.py compare RUN TRUTH [RUN TRUTH ...] [--config '{"k": v}']

`compare` prints per run: bias, MAE and the share of trees with a DBH for each replay (matched
trees of truth DBH >= 10 cm within 15 m of the path, as `forestslam evaluate` scores), and the
paired per-tree DBH change against the SLAM-pose replay (mean +- standard error, median), then
the same pooled over all runs. Needs a truth folder with trajectory.tum (one pose per scan).
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

import numpy as np

from forestslam.evaluation.trees import tree_errors
from forestslam.io import read_trees_csv, read_tum
from forestslam.mapping import tree_map as tm
from forestslam.mapping.config import MappingConfig

CALLS = "tree_map_calls.pkl"


def record(argv: list[str]) -> None:
    """Run `forestslam run ARGV` with TreeMap's add/flush/table calls written to RUN/CALLS."""
    out_dir = Path(argv[argv.index("--out") + 1])
    calls: list = []
    add, flush, table = tm.TreeMap.add, tm.TreeMap.flush, tm.TreeMap.table

    def rec_add(self, scan_index, T, ids, points, base_z, centre_z, scan_dbh):
        lo, hi = self.cfg.dbh_band_m
        band = []
        for k in range(len(ids)):  # only the band is needed: keeps the record small
            p = points[k] if k < len(points) else np.zeros((0, 3))
            h = p[:, 2] - base_z[k]
            band.append(p[(h >= lo) & (h <= hi)].copy() if np.isfinite(base_z[k]) else p[:0])
        args = (scan_index, np.array(T), np.array(ids), band, np.array(base_z))
        calls.append(("add", (*args, np.array(centre_z), np.array(scan_dbh))))
        return add(self, scan_index, T, ids, points, base_z, centre_z, scan_dbh)

    def rec_flush(self, scan_index=None):
        calls.append(("flush", (scan_index,)))
        return flush(self, scan_index)

    def rec_table(self, ids, xy, observations):
        (out_dir / CALLS).write_bytes(pickle.dumps(calls))
        return table(self, ids, xy, observations)

    tm.TreeMap.add, tm.TreeMap.flush, tm.TreeMap.table = rec_add, rec_flush, rec_table
    from forestslam.cli.main import main

    sys.argv = ["forestslam", "run", *argv]
    main()


def replay(run: Path, true_poses: np.ndarray | None, config: dict) -> tm.TreeMap:
    """The recorded calls into a new TreeMap(config), with the true pose of each scan if given."""
    trees = tm.TreeMap(MappingConfig(**config))
    for kind, args in pickle.loads((run / CALLS).read_bytes()):
        if kind == "add":
            i, T, *rest = args
            trees.add(i, T if true_poses is None else true_poses[i], *rest)
        elif kind == "flush":
            trees.flush(*args)
    return trees


def tree_errors_cm(run: Path, truth: Path, trees: tm.TreeMap) -> dict[int, float]:
    """DBH error (cm) per scored truth tree of the run's trees.csv with the replay's DBH."""
    metrics = json.loads((run / "metrics.json").read_text())
    alignment = np.asarray(metrics["trajectory"]["alignment"])
    est, tru = read_trees_csv(run / "trees.csv"), read_trees_csv(truth / "trees.csv")
    _, poses = read_tum(truth / "trajectory.tum")
    dbh = np.array([trees.dbh(int(i) - 1)[0] for i in est["id"]])  # ids are landmarks + 1
    tru_xy = np.c_[tru["x"], tru["y"]]
    est_xyz = np.c_[est["x"], est["y"], np.nan_to_num(est["z"])]
    r = tree_errors(est_xyz, dbh, tru_xy, tru["dbh_m"], poses[:, :2, 3], alignment)
    m = r["match_est_to_truth"]
    k = np.nonzero(m >= 0)[0]
    near = np.hypot(*(tru_xy[:, None, :] - poses[None, :, :2, 3]).transpose(2, 0, 1)).min(1)
    scored = ((tru["dbh_m"] >= 0.1) & (near <= 15))[m[k]]
    pairs = zip(k[scored], m[k][scored], strict=True)
    return {int(t): 100 * (dbh[i] - tru["dbh_m"][t]) for i, t in pairs}


def summary(e: dict[int, float]) -> str:
    v = np.array(list(e.values()))
    ok = np.isfinite(v)
    return f"bias {v[ok].mean():+.2f} MAE {np.abs(v[ok]).mean():.2f} with DBH {ok.mean():.2f}"


def change(base: dict[int, float], other: dict[int, float]) -> np.ndarray:
    common = [t for t in base if np.isfinite(base[t]) and np.isfinite(other.get(t, np.nan))]
    return np.array([other[t] - base[t] for t in common])


def paired(d: np.ndarray) -> str:
    se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
    return f"{d.mean():+.2f} +- {se:.2f} (median {np.median(d):+.2f}, {len(d)} trees)"


def compare(argv: list[str]) -> None:
    config = {}
    if "--config" in argv:
        j = argv.index("--config")
        config, argv = json.loads(argv[j + 1]), argv[:j] + argv[j + 2 :]
    variants = {"slam": (False, {}), "true": (True, {})}
    if config:
        variants |= {"slam+cfg": (False, config), "true+cfg": (True, config)}
    pooled: dict[str, list] = {name: [] for name in variants if name != "slam"}
    for run, truth in zip(argv[::2], argv[1::2], strict=True):
        run, truth = Path(run), Path(truth)
        _, true_poses = read_tum(truth / "trajectory.tum")
        errs = {
            name: tree_errors_cm(run, truth, replay(run, true_poses if gt else None, cfg))
            for name, (gt, cfg) in variants.items()
        }
        print(f"{run}:")
        for name, e in errs.items():
            line = f"  {name:9s} {summary(e)}"
            if name != "slam":
                d = change(errs["slam"], e)
                pooled[name].append(d)
                line += f"; DBH change vs slam {paired(d)}"
            print(line)
    for name, ds in pooled.items():
        print(f"pooled {name:9s} DBH change vs slam {paired(np.concatenate(ds))}")


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in ("record", "compare"):
        sys.exit(__doc__)
    (record if sys.argv[1] == "record" else compare)(sys.argv[2:])
