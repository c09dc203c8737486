"""In-sweep motion of MLS frames estimated from the frame itself (tls.sweep): a vibrating
scanner whose roll / pitch rates change from frame to frame, which the velocity of the previous
frames cannot deskew."""

from __future__ import annotations

import numpy as np
from tls_world import mls_frame, pose, reference_cloud, skewed, stand

from forestslam.odometry.deskew import se3_exp
from forestslam.tls import TlsConfig, register_mls_to_tls
from forestslam.tls.sweep import feature_times


def test_feature_times_follow_the_azimuth():
    rng = np.random.default_rng(3)
    az = rng.uniform(-np.pi, np.pi, 20000)
    pts = np.column_stack([5 * np.cos(az), 5 * np.sin(az), rng.normal(0, 1, len(az))])
    times = (az + np.pi) / (2 * np.pi) * 0.1
    f_az = rng.uniform(-np.pi + 0.05, np.pi - 0.05, 50)
    feats = np.column_stack([3 * np.cos(f_az), 3 * np.sin(f_az), np.zeros(50)])
    got = feature_times(feats, pts, times)
    assert np.all(np.abs(got - (f_az + np.pi) / (2 * np.pi) * 0.1) < 0.1 / 360 + 1e-9)
    assert len(feature_times(np.zeros((0, 3)), pts, times)) == 0
    assert np.all(feature_times(feats, np.zeros((0, 3)), np.zeros(0)) == 0)


def test_vibrating_frames_are_deskewed_by_their_own_sweep():
    trees = stand()
    ref = reference_cloud(trees)
    # Walking at 0.8 m/s; roll and pitch rates of 25 deg/s that flip sign every frame.
    rate = np.radians(25.0)
    twists = [np.array([0.8, 0.0, 0.0, rate * (-1) ** k, -rate * (-1) ** k, 0.0]) for k in range(5)]

    truth, frames = [], []
    for k, w in enumerate(twists):
        T = pose(1.0 + 0.08 * k * np.cos(0.3), -0.5 + 0.08 * k * np.sin(0.3), 0.3)
        truth.append(T)
        frames.append(skewed(mls_frame(trees, T, 0.1 * k, seed=30 + k), w))

    def run(sweep: bool) -> tuple[np.ndarray, np.ndarray]:
        """Translation (m) and rotation (deg) errors of the mid-sweep poses."""
        cfg = TlsConfig()
        cfg.registration.sweep_twist = sweep
        out = register_mls_to_tls(frames, ref, cfg, initial_pose=truth[0])
        assert len(out.frames) == len(truth)
        te, re = [], []
        for rec, T, w in zip(out.frames, truth, twists, strict=True):
            mid = T @ se3_exp(w * rec.t_mid_s)
            te.append(np.linalg.norm(rec.T_tls_mid[:3, 3] - mid[:3, 3]))
            c = (np.trace(mid[:3, :3].T @ rec.T_tls_mid[:3, :3]) - 1) / 2
            re.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
        return np.array(te), np.array(re)

    on, rot_on = run(True)
    off, rot_off = run(False)
    assert np.all(on < 0.015), on
    assert np.all(rot_on < 0.2), rot_on
    assert np.mean(rot_on) < 0.3 * np.mean(rot_off), (rot_on, rot_off)
    assert np.mean(on) < 0.5 * np.mean(off), (on, off)
