"""Is a tree table's local map in the reference trajectory's metric? (issue 21, V03 drift)

Trees of frames k and k+lag are placed in the world by their reference poses and matched; if
the local maps were s times the reference's size about their own poses, the matched trees
would differ by (1 - s) times the step between the poses; if the trees sat b nearer their pose,
by b times the difference of their bearings. Both are fitted (least squares), alone and
together, and the per-pair shortfall is broken down by terrain slope.

    bench/treeloc_scale_check.py SESSION LAG [GRAVITY reference|stems] [MAX_RANGE_M]
"""

import sys

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from treeloc_slam_bench import DATA

from forestslam.io.tree_tables import read_tree_table
from forestslam.localization.tables import query_xy

if len(sys.argv) < 3:
    sys.exit(__doc__)
session = sys.argv[1]
lag = int(sys.argv[2])
grav = sys.argv[3] if len(sys.argv) > 3 else "reference"
rmax = float(sys.argv[4]) if len(sys.argv) > 4 else 20.0
table = read_tree_table(DATA / session)
fr = table.frames
rows_A, rows_b = [], []


def world(k):
    xy, R = query_xy(table, int(k), gravity=grav, max_range_m=rmax)
    T = table.poses[int(k)]
    M = T[:3, :3] @ R.T  # level frame -> world
    yaw = np.arctan2(M[1, 0], M[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s], [s, c]])
    return xy @ Rz.T + T[:2, 3], xy, T[:2, 3]


for i in range(0, len(fr) - lag, 3):
    wk, xk, tk = world(fr[i + lag])
    wj, xj, tj = world(fr[i])
    if len(wk) < 8 or len(wj) < 8:
        continue
    d, idx = cKDTree(wj).query(wk, distance_upper_bound=0.5)
    ok = np.isfinite(d)
    if ok.sum() < 8:
        continue
    pk, pj = wk[ok], wj[idx[ok]]
    uk = (pk - tk) / np.linalg.norm(pk - tk, axis=1)[:, None]
    uj = (pj - tj) / np.linalg.norm(pj - tj, axis=1)[:, None]
    dt = tk - tj
    res = pk - pj
    for a in range(2):
        rows_A.append(np.column_stack([np.full(len(res), dt[a]), (uj - uk)[:, a]]))
        rows_b.append(res[:, a])
A = np.concatenate(rows_A)
b = np.concatenate(rows_b)
sigma_only = np.linalg.lstsq(A[:, :1], b, rcond=None)[0]
both = np.linalg.lstsq(A, b, rcond=None)[0]
off_only = np.linalg.lstsq(A[:, 1:], b, rcond=None)[0]


def r(x, cols):
    return np.sqrt(np.mean((b - A[:, cols] @ x) ** 2))


print(f"{session} lag {lag} gravity {grav} rmax {rmax}: n={len(b) // 1}")
print(
    f"  scale-only: step short by {sigma_only[0] * 100:.3f} % rms {r(sigma_only, [0, 1][:1]):.4f}"
)
print(f"  offset-only: trees {off_only[0] * 100:.2f} cm nearer rms {r(off_only, [1]):.4f}")
print(
    f"  both: short {both[0] * 100:.3f} %, offset {both[1] * 100:.2f} cm, rms {r(both, [0, 1]):.4f}"
)
# per-pair sigma vs slope, speed, along-track
sig, slope, dist, zs = [], [], [], []
for i in range(0, len(fr) - lag, 3):
    wk, xk, tk = world(fr[i + lag])
    wj, xj, tj = world(fr[i])
    if len(wk) < 8 or len(wj) < 8:
        continue
    d, idx = cKDTree(wj).query(wk, distance_upper_bound=0.5)
    ok = np.isfinite(d)
    if ok.sum() < 8:
        continue
    dt = tk - tj
    n = np.linalg.norm(dt)
    if n < 2:
        continue
    m = np.median(wk[ok] - wj[idx[ok]], axis=0)
    sig.append(m @ dt / n**2)
    dz = table.poses[int(fr[i + lag])][2, 3] - table.poses[int(fr[i])][2, 3]
    slope.append(abs(dz) / n)
    dist.append(n)
    zs.append(dz / n)
sig, slope, dist, zs = map(np.array, (sig, slope, dist, zs))
print(f"  per-pair median sigma {np.median(sig) * 100:.3f} %, mean {np.mean(sig) * 100:.3f} %")
for lo, hi in [(0, 0.03), (0.03, 0.08), (0.08, 0.15), (0.15, 1)]:
    s = (slope >= lo) & (slope < hi)
    print(
        f"   slope {lo}-{hi}: n {s.sum()} shortfall mean {np.mean(sig[s]) * 100:.3f} %, "
        f"median {np.median(sig[s]) * 100:.3f} %"
    )
print("   uphill mean", np.mean(sig[zs > 0.05]) * 100, "downhill", np.mean(sig[zs < -0.05]) * 100)
