"""The stem-centre residual gate of the MLS-to-TLS merge follows the walk's own verified
frames (tls.acceptance): oval and polygonal stems give correctly placed frames residuals above
a fixed gate, and such frames are tested further instead of dropped; a gross outlier is not."""

from __future__ import annotations

import numpy as np
from tls_world import oval_mls_frame, oval_reference_cloud, oval_stand, pose

from forestslam.tls import TlsConfig, register_mls_to_tls
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


def test_the_gate_never_drops_below_the_fixed_one_nor_learns_from_nan_or_few_pairs():
    cfg = MapConfig()
    gate = VirtualResidualGate(cfg)
    for _ in range(50):
        gate.add(100, 0.008)  # a clean round-stem walk: 8 mm residuals
    gate.add(100, float("nan"))
    gate.add(cfg.accept_min_virtual_inliers - 1, 0.05)
    assert gate.limit() == cfg.accept_virtual_rms_m
    assert len(gate.trusted) == 50


def test_a_walk_among_polygonal_oval_stems_is_merged_where_a_fixed_gate_drops_it():
    """End to end: polygonal (9-16 corners), 10 % oval stems give correctly placed frames
    stem-centre residuals of 0.6-1.2 cm here. With the fixed gate set below that (as 3 cm is
    below the residuals of the bench's style-b stems), no frame joins the map; the learnt
    gate merges them, each one still checked on the reference, all within 1 cm of the truth."""
    ovals = oval_stand(ovality=0.1)
    ref = oval_reference_cloud(ovals)
    truth = [pose(-4.0 + 0.25 * k, -1.0 + 0.05 * k, 0.2 + 0.01 * k) for k in range(16)]
    frames = [oval_mls_frame(ovals, T, 0.1 * k, seed=60 + k) for k, T in enumerate(truth)]
    merged = {}
    for learnt in (False, True):
        cfg = TlsConfig()
        cfg.map.accept_virtual_rms_m = 0.005
        cfg.map.accept_virtual_rms_min_frames = 5 if learnt else 10**6
        run = register_mls_to_tls(frames, ref, cfg, initial_pose=truth[0])
        errors = [
            np.linalg.norm(r.T_tls_sensor[:3, 3] - T[:3, 3])
            for r, T in zip(run.frames, truth, strict=True)
        ]
        assert max(errors) < 0.01, errors
        assert all(r.virtual_rms_m > 0.005 for r in run.frames)
        merged[learnt] = [r.accepted for r in run.frames]
    assert not any(merged[False])
    assert sum(merged[True]) >= len(frames) - 6, merged[True]
