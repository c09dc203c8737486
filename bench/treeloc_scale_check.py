"""Is a tree table's local map in the reference trajectory's metric? (issue 21, V03 drift)

Trees of frames k and k+lag are placed in the world by their reference poses and matched; if
the local maps were s times the reference's size about their own poses, the matched trees
would differ by (1 - s) times the step between the poses; if the trees sat b nearer their pose,
by b times the difference of their bearings. Both are fitted (least squares), alone and
together, and the per-pair shortfall is broken down by terrain slope.

    bench/treeloc_scale_check.py SESSION LAG [GRAVITY reference|stems] [MAX_RANGE_M]
"""

import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from treeloc_slam_bench import DATA

from forestslam.geometry import rot2, yaw_of
from forestslam.io.tree_tables import read_tree_table
from forestslam.localization.tables import query_xy

MIN_PAIRS = 8
MATCH_M = 0.5


def world_trees(table, k: int, gravity: str, max_range_m: float):
    """Frame k's trees in the world by its reference pose (levelled), and the pose's xy."""
    xy, R = query_xy(table, k, gravity=gravity, max_range_m=max_range_m)
    T = table.poses[k]
    yaw = float(yaw_of(T[:3, :3] @ R.T))  # level frame -> world
    return xy @ rot2(yaw).T + T[:2, 3], T[:2, 3]


def matched_frames(table, lag: int, gravity: str, max_range_m: float):
    """(index, matched trees of frame i+lag, their partners in frame i, both poses' xy)."""
    fr = table.frames
    for i in range(0, len(fr) - lag, 3):
        wk, tk = world_trees(table, int(fr[i + lag]), gravity, max_range_m)
        wj, tj = world_trees(table, int(fr[i]), gravity, max_range_m)
        if len(wk) < MIN_PAIRS or len(wj) < MIN_PAIRS:
            continue
        d, idx = cKDTree(wj).query(wk, distance_upper_bound=MATCH_M)
        ok = np.isfinite(d)
        if ok.sum() >= MIN_PAIRS:
            yield i, wk[ok], wj[idx[ok]], tk, tj


def scale_offset_fit(pairs) -> None:
    """Least squares of the residuals on the step (scale) and the bearing change (offset)."""
    rows_A, rows_b = [], []
    for _, pk, pj, tk, tj in pairs:
        uk = (pk - tk) / np.linalg.norm(pk - tk, axis=1)[:, None]
        uj = (pj - tj) / np.linalg.norm(pj - tj, axis=1)[:, None]
        res = pk - pj
        for a in range(2):
            rows_A.append(np.column_stack([np.full(len(res), (tk - tj)[a]), (uj - uk)[:, a]]))
            rows_b.append(res[:, a])
    A, b = np.concatenate(rows_A), np.concatenate(rows_b)

    def fit(cols):
        x = np.linalg.lstsq(A[:, cols], b, rcond=None)[0]
        return x, np.sqrt(np.mean((b - A[:, cols] @ x) ** 2))

    (scale,), r_scale = fit([0])
    (offset,), r_offset = fit([1])
    (s2, o2), r_both = fit([0, 1])
    print(f"  n={len(b)}")
    print(f"  scale-only: step short by {scale * 100:.3f} % rms {r_scale:.4f}")
    print(f"  offset-only: trees {offset * 100:.2f} cm nearer rms {r_offset:.4f}")
    print(f"  both: short {s2 * 100:.3f} %, offset {o2 * 100:.2f} cm, rms {r_both:.4f}")


def shortfall_by_slope(table, pairs, lag: int) -> None:
    """Per frame pair: the median residual along the step, by the terrain slope between them."""
    fr = table.frames
    sig, slope, zs = [], [], []
    for i, pk, pj, tk, tj in pairs:
        dt = tk - tj
        n = np.linalg.norm(dt)
        if n < 2:
            continue
        sig.append(np.median(pk - pj, axis=0) @ dt / n**2)
        dz = table.poses[int(fr[i + lag])][2, 3] - table.poses[int(fr[i])][2, 3]
        slope.append(abs(dz) / n)
        zs.append(dz / n)
    sig, slope, zs = map(np.array, (sig, slope, zs))
    print(f"  per-pair median sigma {np.median(sig) * 100:.3f} %, mean {np.mean(sig) * 100:.3f} %")
    for lo, hi in [(0, 0.03), (0.03, 0.08), (0.08, 0.15), (0.15, 1)]:
        s = (slope >= lo) & (slope < hi)
        print(
            f"   slope {lo}-{hi}: n {s.sum()} shortfall mean {np.mean(sig[s]) * 100:.3f} %, "
            f"median {np.median(sig[s]) * 100:.3f} %"
        )
    up, down = np.mean(sig[zs > 0.05]) * 100, np.mean(sig[zs < -0.05]) * 100
    print(f"   uphill mean {up:.3f} %, downhill {down:.3f} %")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    session, lag = sys.argv[1], int(sys.argv[2])
    gravity = sys.argv[3] if len(sys.argv) > 3 else "reference"
    max_range_m = float(sys.argv[4]) if len(sys.argv) > 4 else 20.0
    table = read_tree_table(DATA / session)
    pairs = list(matched_frames(table, lag, gravity, max_range_m))
    print(f"{session} lag {lag} gravity {gravity} rmax {max_range_m}:")
    scale_offset_fit(pairs)
    shortfall_by_slope(table, pairs, lag)
