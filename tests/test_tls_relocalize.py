"""MLS-to-TLS tracking loss: after a jump the motion model cannot explain, frames are not
trusted, never join the map, and the frame is placed afresh on the reference's stems."""

from __future__ import annotations

import numpy as np
from tls_world import mls_frame, pose, reference_cloud, stand

from forestslam.tls import TlsConfig, register_mls_to_tls


def test_tracking_loss_is_recovered_on_the_reference_stems():
    trees = stand()
    ref = reference_cloud(trees)
    before = [pose(1.0 + 0.4 * k, -0.5 + 0.1 * k, 0.3 + 0.02 * k) for k in range(3)]
    # A 5 m jump with a quarter turn (e.g. frames dropped by the recorder), then a steady walk.
    after = [pose(-3.0 + 0.3 * k, 3.5, 1.8) for k in range(6)]
    truth = before + after
    frames = [mls_frame(trees, T, 0.1 * k, seed=20 + k) for k, T in enumerate(truth)]
    run = register_mls_to_tls(frames, ref, TlsConfig())
    assert len(run.frames) == len(truth)
    cfg = TlsConfig()
    lost = cfg.registration.relocalize_after_frames
    errors = [
        np.linalg.norm(r.T_tls_sensor[:3, 3] - T[:3, 3])
        for r, T in zip(run.frames, truth, strict=True)
    ]
    assert all(e < 0.01 for e in errors[:3]), errors
    # Frames placed wrongly never join the map ...
    for rec, err in zip(run.frames, errors, strict=True):
        assert not (rec.accepted and err > 0.05), errors
    # ... and tracking is back at the latest once the loss is declared.
    assert all(e < 0.01 for e in errors[3 + lost :]), errors
    assert all(r.accepted for r in run.frames[3 + lost + 1 :])
