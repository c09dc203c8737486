"""The stem-centre residual gate of the MLS-to-TLS merge, learnt from the walk's own frames.

A frame's virtual (stem-centre) residual is d - r between its ring circles and the target's
stem walls. For a correct pose it is the range noise plus how far the stems are from circles:
polygonal, oval, flared and barked sections against one-sided ring fits. Those depend on the
plot and the scanner, so no fixed RMS fits every plot (bench/tls_bench.py --style b,
longleaf-lawn-20m-b: frames within 2 cm of the truth at 1.2-4.5 cm RMS, half of them above the
old fixed 3 cm; style a mostly below it). The gate is an outlier test against the residuals of
the walk's trusted frames (converged, not degenerate, real-feature residual and correction
within their gates, enough virtual pairs): a frame passes when its RMS lies within `sigmas`
robust standard deviations (1.4826 x the median absolute deviation) above their median. Median
and MAD hold while fewer than half of those frames are wrong; as the walk is tracked (>= 98 %
of frames within 10 cm on the bench), they are the residuals of correct poses. Before
`min_frames` are known, and as a floor, the fixed gate holds. The gate only decides which
frames are tested further: a frame joins the map only when its stems also sit on the
reference's stems and its pose holds on the reference alone (pipeline._ReferenceCheck).
Not done: a chi-square test of each pair residual against a per-pair sigma (the stems' own
non-circularity, the ring fit's noise): the LM reports the RMS only.
"""

from __future__ import annotations

import numpy as np

from forestslam.tls.config import MapConfig


class VirtualResidualGate:
    """The largest virtual RMS (m) a frame may have to be tested for the merge."""

    def __init__(self, config: MapConfig):
        self.config = config
        self.trusted: list[float] = []

    def add(self, inliers: int, rms_m: float) -> None:
        """A trusted frame's virtual pairs and their RMS (kept with enough pairs)."""
        if inliers >= self.config.accept_min_virtual_inliers and np.isfinite(rms_m):
            self.trusted.append(float(rms_m))

    def limit(self) -> float:
        cfg = self.config
        if len(self.trusted) < cfg.accept_virtual_rms_min_frames:
            return cfg.accept_virtual_rms_m
        rms = np.asarray(self.trusted)
        median = float(np.median(rms))
        spread = 1.4826 * float(np.median(np.abs(rms - median)))
        return max(cfg.accept_virtual_rms_m, median + cfg.accept_virtual_rms_sigmas * spread)

    def passes(self, inliers: int, rms_m: float) -> bool:
        """Enough virtual pairs, and their RMS within the gate."""
        return inliers >= self.config.accept_min_virtual_inliers and rms_m <= self.limit()
