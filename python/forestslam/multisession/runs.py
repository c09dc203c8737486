"""`forestslam merge RUN_A RUN_B --out DIR`: two run directories, one map in A's frame."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from forestslam.errors import InputError
from forestslam.multisession.level import level_fit
from forestslam.multisession.merge import MergeConfig, align_tree_maps, fuse_trees

log = logging.getLogger(__name__)


def _load_run(run_dir: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    from forestslam.io import read_trees_csv, read_tum

    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: not a run directory")
    trees_path, traj_path = run_dir / "trees.csv", run_dir / "trajectory.tum"
    for path in (trees_path, traj_path):
        if not path.is_file():
            raise InputError(f"{run_dir}: no {path.name} (a slam or map3d run writes it)")
    stamps, poses = read_tum(traj_path)
    return read_trees_csv(trees_path), stamps, poses


def _levelled(a: dict, b: dict, alignment, config: MergeConfig):
    """The planar placement made 3D on the matched trees' centres when both maps have
    heights (see forestslam.multisession.level); as it was otherwise."""
    if "z" not in a or "z" not in b:
        return alignment
    ia, ib = alignment.pairs[:, 0], alignment.pairs[:, 1]
    levelled = level_fit(
        np.column_stack([b["x"], b["y"], b["z"]])[ib],
        np.column_stack([a["x"], a["y"], a["z"]])[ia],
        config.level_min_trees,
        config.level_max_tilt_deg,
    )
    if levelled is None:
        return alignment
    log.info("B levelled on A: tilt %.2f deg over %d trees", levelled[1], levelled[2])
    return replace(alignment, T_a_b=levelled[0], tilt_deg=levelled[1])


def merge_runs(
    run_a: str | Path, run_b: str | Path, out_dir: str | Path, config: MergeConfig = MergeConfig()
) -> dict:
    """Place B in A, write merged trees and both trajectories in A's frame; returns merge.yaml."""
    from forestslam.io import write_trees_csv, write_trees_geojson, write_tum
    from forestslam.io.atomic import atomic_write_text
    from forestslam.mapping.plot import plot_map

    run_a, run_b, out = Path(run_a), Path(run_b), Path(out_dir)
    a, stamps_a, poses_a = _load_run(run_a)
    b, stamps_b, poses_b = _load_run(run_b)
    alignment = align_tree_maps(
        np.column_stack([a["x"], a["y"]]),
        np.column_stack([b["x"], b["y"]]),
        poses_b[:, :2, 3],
        config,
    )
    alignment = _levelled(a, b, alignment, config)
    merged = fuse_trees(a, b, alignment)
    poses_b_in_a = np.einsum("ij,kjl->kil", alignment.T_a_b, poses_b)
    write_tum(out / "trajectory_a.tum", stamps_a, poses_a)
    write_tum(out / "trajectory_b.tum", stamps_b, poses_b_in_a)
    write_trees_csv(out / "trees.csv", merged)
    write_trees_geojson(out / "trees.geojson", merged)
    summary = {
        "run_a": str(run_a),
        "run_b": str(run_b),
        "T_a_b": np.round(alignment.T_a_b, 9).tolist(),
        **alignment.to_dict(),
        "trees": {
            "merged": int(len(merged["id"])),
            "both": int(np.sum(merged["source"] == "both")),
            "a_only": int(np.sum(merged["source"] == "a")),
            "b_only": int(np.sum(merged["source"] == "b")),
        },
    }
    atomic_write_text(out / "merge.yaml", yaml.safe_dump(summary, sort_keys=False))
    plot_map(
        out / "map.png",
        poses_a[:, :2, 3],
        poses_b_in_a[:, :2, 3],
        np.column_stack([merged["x"], merged["y"]]),
        merged["dbh_m"],
        title=f"merged: {len(merged['id'])} trees ({summary['trees']['both']} in both runs)",
    )
    return summary
