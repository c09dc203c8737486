"""Accumulated silhouette: the DBH of a stem thinner than one scan resolves, measured over many
scans (Gupta et al.'s "accumulated" protocol for thin stems).

One scan line crosses a stem of width w seen from range rho with beams one azimuth step
s = rho x step apart: k of them hit it, k = floor(w / s) or ceil(w / s) depending on where
the azimuth grid falls (its phase). Over phases drawn uniformly, E[k x s] = w exactly, for any
w / s, as long as the lines with no hit (k = 0, a stem under one step) count as well. A single
scan's silhouette needs >= 2 returns on >= 2 lines, so it keeps the wide phases only (up to 2x
the width under 2 steps: TreeMap's resolution gate). Here every line that crosses the stem's
breast-height band counts, from the sensor's known ring elevations, whether it hit or not:
the sensor moves between scans, the grid falls on the stem at other phases, and the mean of
k x s over lines converges to the width. A line with a return nearer than the stem within
the collection reach (an occluder) is left out.

Which returns are the stem's: every scan keeps the returns near the stem's predicted centre
(the detections', within `reach`) in the map frame; at the end the centre is the mode of all
of them (mean shift: a stem's returns pile up on its surface, shrub or foliage returns spread
over their volume), a hit is a return within `window` across and `depth` along the view ray
of that centre, and the returns in the same depth just beside the window (the same width on
both sides) are the background (shrubs, foliage, branches around a sapling) taken off.

The width comes from the raw returns (perception's stem points would select the scans where a
thin stem was detected, which are the ones with more hits). Points are deskewed to the scan's
stamp with the motion between the last two scans (planar, constant velocity) when the scan has
per-point times. Ring elevations are taken from the data (mean tan(elevation) per ring).

What it assumes: a beam returns from the stem when its centre line meets it (a thin ray).
A real beam's footprint (divergence x range) can return from a partly hit edge and widen the
width by up to that footprint: not modelled here (see README, DBH).
"""

from __future__ import annotations

import numpy as np

# Returns kept per scan around a stem's predicted centre (m across and along the view ray):
# the centre window and the background beside it (2 x MappingConfig.dbh_sweep_window_m),
# plus the detections' centre error (a few cm).
REACH_M = 0.3
# Kernel of the mean shift that finds the stem's centre among the kept returns: about the
# SLAM's per-scan lateral pose noise at 10-20 m (2.7-4 cm), so the stem's hits count as one.
CENTRE_KERNEL_M = 0.05
# Reach of TreeMap.is_empty's count (m across and along the view ray of the detections'
# centre): a stem placed 0.5 m off, or a copy 0.6-1.3 m beside it, has none within it.
EMPTY_REACH_M = 0.25


def ring_tangents(points: np.ndarray, ring: np.ndarray, min_range_m: float = 2.0) -> np.ndarray:
    """Mean tan(elevation) per ring (R,) of a scan's points (N,3) (NaN for rings without
    returns beyond min_range_m): the rings' elevations in the sensor frame."""
    rho = np.hypot(points[:, 0], points[:, 1])
    ok = rho > min_range_m
    r = ring[ok].astype(np.int64)
    n = np.bincount(r, minlength=int(ring.max()) + 1 if len(ring) else 0)
    s = np.bincount(r, weights=points[ok, 2] / rho[ok], minlength=len(n))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def collect_lines(
    points: np.ndarray,
    ring: np.ndarray,
    ring_tan: np.ndarray,
    centre: np.ndarray,
    up: np.ndarray,
    band: tuple[float, float],
    reach_m: float,
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """One scan's lines across a stem: points (N,3) and their rings (N,) near the stem (sensor
    frame), ring_tan (R,) the rings' tan(elevation), centre (3,) the stem's predicted
    breast-height centre and up (3,) the map's vertical, both in the sensor frame. A ring
    crosses the stem when its beam at the stem's azimuth and range lies within band (lo, hi) of
    breast height. Returns (the crossing rings, the rows of the points on them within reach_m
    across the view ray of the centre and not beyond reach_m behind it (hits, background and
    whatever stands in front), the crossing rings with no return within reach_m across that is
    more than reach_m nearer, the points within EMPTY_REACH_M of the centre across and along on
    those rings: TreeMap.is_empty's evidence)."""
    rho = float(np.hypot(centre[0], centre[1]))
    u = centre[:2] / rho
    a = np.array([-u[1], u[0]])
    q = np.c_[np.full(len(ring_tan), centre[0]), np.full(len(ring_tan), centre[1]), rho * ring_tan]
    h = (q - centre) @ up
    crossing = np.isfinite(h) & (h >= band[0]) & (h <= band[1])
    r = ring.astype(np.int64)
    valid = r < len(ring_tan)
    r = np.where(valid, r, 0)
    along = points[:, :2] @ u
    inside = valid & crossing[r] & (np.abs(points[:, :2] @ a) <= reach_m) & (along > 0)
    occluded = np.bincount(r[inside & (along < rho - reach_m)], minlength=len(ring_tan)) > 0
    use = crossing & ~occluded
    e = EMPTY_REACH_M
    near = inside & use[r] & (np.abs(along - rho) <= e) & (np.abs(points[:, :2] @ a) <= e)
    kept = np.flatnonzero(inside & (along <= rho + reach_m))
    return np.flatnonzero(crossing), kept, int(use.sum()), int(near.sum())


def stem_centre(xy: np.ndarray, start: np.ndarray, kernel_m: float, rounds: int = 10) -> np.ndarray:
    """Mode of the kept returns xy (M,2) (map frame) within REACH_M of start (2,): the return
    with the most others within kernel_m (a stem's returns pile up on its surface, a shrub's
    or foliage's spread over their volume; the detections' centre of a far sapling can be off
    by more than the kernel), refined by mean shift with a flat kernel of kernel_m."""
    c = np.asarray(start, dtype=np.float64)
    pts = xy[np.linalg.norm(xy - c, axis=1) <= REACH_M]
    if len(pts) == 0:
        return c
    pts = pts[:: max(1, len(pts) // 300)]  # bounded pairwise counts (the seed only)
    d2 = np.sum((pts[:, None, :] - pts[None, :, :]) ** 2, axis=2)
    c = pts[int(np.argmax(np.count_nonzero(d2 <= kernel_m**2, axis=1)))]
    for _ in range(rounds):
        near = np.linalg.norm(xy - c, axis=1) <= kernel_m
        nxt = xy[near].mean(axis=0)
        if np.linalg.norm(nxt - c) < 1e-4:
            return nxt
        c = nxt
    return c


def net_hits(
    xy: np.ndarray,
    ring: np.ndarray,
    scan: np.ndarray,
    lines: list[np.ndarray],
    origins: np.ndarray,
    centre: np.ndarray,
    window_m: float,
    depth_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scan, the lines across the stem and their net hits, from the kept returns xy (M,2)
    (map frame) with their rings (M,) and scans (M,), each scan's crossing rings (lines[g]) and
    sensor position (origins (G,2)), around the stem centre (2,). A hit lies within window_m
    across and depth_m along the view ray of the centre; the background is what lies in the
    same depth within window_m beyond it on either side (the same width), taken off. A line
    with a return in front of that depth within 2 window_m across (a shrub's leaves, a branch)
    is left out: the stem may be hidden behind it. Returns (lines (G,), net hits (G,), the
    hits' offsets across the view ray)."""
    view = centre - origins
    dist = np.linalg.norm(view, axis=1)
    u = view / np.maximum(dist, 1e-9)[:, None]
    d = xy - centre
    lat = np.einsum("ij,ij->i", d, np.c_[-u[scan, 1], u[scan, 0]])
    along = np.einsum("ij,ij->i", d, u[scan])
    n_rings = int(max(ring.max(initial=0), max((int(x.max(initial=0)) for x in lines), default=0)))
    key = scan * (n_rings + 1) + ring
    front = (np.abs(lat) <= 2 * window_m) & (along < -depth_m)
    occluded = np.zeros(len(origins) * (n_rings + 1), dtype=bool)
    occluded[key[front]] = True
    deep = (np.abs(along) <= depth_m) & ~occluded[key]
    central = deep & (np.abs(lat) <= window_m)
    side = deep & (np.abs(lat) > window_m) & (np.abs(lat) <= 2 * window_m)
    n_lines = np.array(
        [np.count_nonzero(~occluded[g * (n_rings + 1) + rr]) for g, rr in enumerate(lines)]
    )
    g = len(origins)
    net = np.bincount(scan[central], minlength=g) - np.bincount(scan[side], minlength=g)
    return n_lines.astype(np.float64), net.astype(np.float64), lat[central]


def accumulated_width(
    step_m: np.ndarray,
    hits: np.ndarray,
    lines: np.ndarray,
    block_scans: int,
) -> tuple[float, float]:
    """Width sum(k s) / sum(lines) over scans (s (n,) the azimuth step at the stem, hits (n,),
    lines (n,)) and its standard error, the larger of: a ratio estimator over blocks of
    block_scans consecutive scans (scans close in time share their phase when the stem's
    bearing changes slowly), Bessel-corrected, inf with fewer than 2 blocks; and the phase
    error of independent scans (the lines of one scan share its phase: k is floor or ceil of
    width / s, with the fraction f of width / s as the chance of ceil, variance s^2 f (1 - f)
    per scan)."""
    ks = step_m * hits
    total = float(lines.sum())
    width = float(ks.sum()) / total
    nb = int(np.ceil(len(ks) / block_scans))
    if nb < 2:
        return width, float("inf")
    idx = np.arange(len(ks)) // block_scans
    kb = np.bincount(idx, weights=ks, minlength=nb)
    lb = np.bincount(idx, weights=lines, minlength=nb)
    var = nb / (nb - 1) * float(np.sum((kb - width * lb) ** 2)) / total**2
    f = np.mod(width / step_m, 1.0)
    var_phase = float(np.sum((lines * step_m) ** 2 * f * (1 - f))) / total**2
    return width, float(np.sqrt(max(var, var_phase)))
