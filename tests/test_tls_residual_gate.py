"""The stem-centre residual gate of the MLS-to-TLS merge follows the walk's own verified
frames (tls.acceptance): oval and polygonal stems give correctly placed frames residuals above
a fixed gate, and such frames are tested further instead of dropped; a gross outlier is not."""

from __future__ import annotations

import numpy as np

from forestslam.tls.acceptance import VirtualResidualGate
from forestslam.tls.config import MapConfig


def test_the_fixed_gate_holds_until_enough_frames_are_trusted():
    cfg = MapConfig()
    gate = VirtualResidualGate(cfg)
    for _ in range(cfg.accept_virtual_rms_min_frames - 1):
        gate.add(100, 0.029)
    assert gate.limit() == cfg.accept_virtual_rms_m
    assert not gate.passes(100, 0.031)
    assert not gate.passes(cfg.accept_min_virtual_inliers - 1, 0.01)


def test_frames_on_oval_stems_pass_when_the_walk_s_trusted_frames_look_alike():
    # Trusted frames of a walk among polygonal, oval stems (bench/tls_bench.py --style b,
    # longleaf-lawn-20m-b: 2.0-3.0 cm, median ~2.5 cm for frames within 2 cm of the truth).
    rng = np.random.default_rng(3)
    cfg = MapConfig()
    gate = VirtualResidualGate(cfg)
    for rms in np.clip(rng.normal(0.025, 0.0035, 40), 0.012, cfg.accept_virtual_rms_m):
        gate.add(100, float(rms))
    limit = gate.limit()
    # median + 3 robust sigmas of those: 3.3-3.9 cm
    assert 0.033 < limit < 0.039, limit
    assert gate.passes(150, 0.033)  # an oval-stem frame: tested on the reference, not dropped
    # A frame placed a stem radius off (residuals of decimetres) stays out.
    assert not gate.passes(150, 0.06)


def test_the_gate_never_drops_below_the_fixed_one_and_ignores_non_finite_values_and_frames_with_few_pairs():
    cfg = MapConfig()
    gate = VirtualResidualGate(cfg)
    for _ in range(50):
        gate.add(100, 0.008)  # a clean round-stem walk: 8 mm residuals
    gate.add(100, float("nan"))
    gate.add(cfg.accept_min_virtual_inliers - 1, 0.05)
    assert gate.limit() == cfg.accept_virtual_rms_m
    assert len(gate.trusted) == 50
