"""How far a least-squares circle of a simulated stem's exact breast-height section lies from its
truth DBH (the tape girth: convex-hull perimeter / pi): the part of any circle-fit bias that is
the truth's definition, not the measurement.
Usage: python bench/dbh_truth_gap.py SIM_DIR [SIM_DIR ...] (`forestslam simulate` outputs)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from forestslam import _core
from forestslam.sim.forest import BREAST_HEIGHT_M, girth_dbh, section_points
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.world import build_world


def gap(sim: Path) -> tuple[int, float, float]:
    """Trees >= 10 cm, mean (circle - tape) DBH in cm and in per cent."""
    cfg = load_scenario(sim / "truth" / "scenario.yaml")
    stems = build_world(cfg).forest.stems
    bh = np.nonzero((stems[:, 9] <= BREAST_HEIGHT_M) & (BREAST_HEIGHT_M < stems[:, 10]))[0]
    sections = section_points(stems[bh], int(cfg.seed), np.full(len(bh), BREAST_HEIGHT_M))
    tape = girth_dbh(sections)
    options = _core.CircleFitConfig()
    options.inlier_threshold_m = 0.05
    circle = np.array(
        [2 * _core.fit_circle(np.ascontiguousarray(s), options).radius for s in sections]
    )
    big = tape >= 0.1
    return (
        int(big.sum()),
        100 * float(np.mean((circle - tape)[big])),
        100 * float(np.mean((circle / tape - 1)[big])),
    )


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        n, cm, rel = gap(Path(arg))
        print(f"{arg}: {n} trees >= 10 cm, LSQ circle - tape DBH {cm:+.2f} cm ({rel:+.2f} %)")
