"""What joins the MLS-to-TLS map: a stale velocity is dropped (it would distort and misplace
every frame after a gap), and a frame whose pose does not hold on the TLS reference alone is
not merged."""

from __future__ import annotations

import numpy as np
from tls_world import mls_frame, pose, reference_cloud, stand

from forestslam.tls import TlsConfig, register_mls_to_tls
from forestslam.tls.features import frame_features
from forestslam.tls.pipeline import _ReferenceCheck


def test_stale_velocity_is_dropped_after_a_gap():
    trees = stand()
    ref = reference_cloud(trees)
    # A fast turn (0.03 rad and 0.05 m per 0.1 s) ...
    before = [pose(1.0 + 0.05 * k, -0.5, 0.3 + 0.03 * k) for k in range(4)]
    frames = [mls_frame(trees, T, 0.1 * k, seed=40 + k) for k, T in enumerate(before)]
    # ... then 2 s without frames, the operator standing still: a 17 deg/s turn rate kept
    # over the gap would deskew these frames by +-0.9 deg and predict them 34 deg off.
    after = [pose(1.2, -0.5, 0.4) for _ in range(3)]
    frames += [
        mls_frame(trees, T, 2.3 + 0.1 * k, seed=50 + k, with_times=True)
        for k, T in enumerate(after)
    ]
    cfg = TlsConfig()
    run = register_mls_to_tls(frames, ref, cfg)
    assert len(run.frames) == len(frames)
    gap = run.frames[len(before)]
    assert np.all(gap.deskew_twist == 0.0)
    for rec, T in zip(run.frames, before + after, strict=True):
        assert np.linalg.norm(rec.T_tls_sensor[:3, 3] - T[:3, 3]) < 0.01
    assert gap.accepted


def test_reference_check_rejects_a_frame_placed_a_few_cm_off():
    trees = stand()
    ref = reference_cloud(trees)
    T_true = pose(1.0, -0.5, 0.3)
    scan = mls_frame(trees, T_true, 0.0, seed=3)
    feats = frame_features(scan.points, scan.ring, TlsConfig().features)
    check = _ReferenceCheck(ref, TlsConfig())
    ok, r = check(feats, T_true)
    assert ok and r["correction_m"] < 0.01
    for offset in ([0.06, 0.0, 0.0], [0.0, -0.05, 0.04]):
        T_off = T_true.copy()
        T_off[:3, 3] += offset
        ok, r = check(feats, T_off)
        assert not ok, r["correction_m"]
    # A rotation error of 1 deg about the vertical is caught as well.
    c, s = np.cos(np.radians(1.0)), np.sin(np.radians(1.0))
    T_rot = T_true.copy()
    T_rot[:2, :2] = T_true[:2, :2] @ np.array([[c, -s], [s, c]])
    ok, r = check(feats, T_rot)
    assert not ok, (r["correction_m"], r["correction_deg"])
