"""The stem-centre residual gate of the MLS-to-TLS merge, learnt from the walk's own frames.

A frame's virtual (stem-centre) residual is d - r between its ring circles and the target's
stem walls. For a correct pose it is the range noise plus how far the stems are from circles:
polygonal, oval and barked sections against one-sided ring fits. Those depend on the plot and
the scanner, so no fixed RMS fits every plot (bench/tls_bench.py --style b: frames within 2 cm
of the truth at 1.2-4.5 cm RMS; style a mostly below 3 cm). The gate is an outlier test
against the residuals of the frames this walk has already verified on the TLS reference alone
(pipeline._ReferenceCheck): a frame passes when its RMS lies within `sigmas` robust standard
deviations (1.4826 x the median absolute deviation) above their median. Before `min_frames`
are verified, and as a floor, the fixed gate holds. The gate decides only which frames are
tested further: a frame joins the map only when its pose also holds on the reference alone.
"""

from __future__ import annotations

import numpy as np

from forestslam.tls.config import MapConfig


class VirtualResidualGate:
    """The largest virtual RMS (m) a frame may have to be tested for the merge."""

    def __init__(self, config: MapConfig):
        self.config = config
        self.verified: list[float] = []

    def add(self, rms_m: float) -> None:
        """A frame verified on the reference (merged) with this virtual RMS."""
        if np.isfinite(rms_m):
            self.verified.append(float(rms_m))

    def limit(self) -> float:
        cfg = self.config
        if len(self.verified) < cfg.accept_virtual_rms_min_frames:
            return cfg.accept_virtual_rms_m
        rms = np.asarray(self.verified)
        median = float(np.median(rms))
        spread = 1.4826 * float(np.median(np.abs(rms - median)))
        return max(cfg.accept_virtual_rms_m, median + cfg.accept_virtual_rms_sigmas * spread)

    def passes(self, inliers: int, rms_m: float) -> bool:
        """Enough virtual pairs, and their RMS within the gate."""
        return inliers >= self.config.accept_min_virtual_inliers and rms_m <= self.limit()
