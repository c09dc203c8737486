"""Frames that did not join the map take their position from the merged frames around them."""

from __future__ import annotations

import numpy as np

from forestslam.geometry import planar_pose
from forestslam.tls.bridging import bridge_unmerged
from forestslam.tls.pipeline import FrameRecord


def record(stamp: float, x: float, y: float, yaw_deg: float, accepted: bool) -> FrameRecord:
    T = planar_pose(x, y, np.radians(yaw_deg))
    T_stamp = T.copy()
    T_stamp[0, 3] -= 0.04  # the sweep start, 5 cm before mid-sweep at 0.8 m/s
    return FrameRecord(
        stamp=stamp,
        T_tls_sensor=T_stamp,
        accepted=accepted,
        converged=True,
        degenerate=False,
        virtual_inliers=100,
        virtual_rms_m=0.04,
        real_inliers=100,
        real_rms_m=0.08,
        ms_features=0.0,
        ms_lm=0.0,
        ms_ndt=0.0,
        t_mid_s=0.05,
        T_tls_mid=T,
        reason="" if accepted else "stem pairs too few or loose (100 pairs, 4.0 cm RMS)",
    )


def test_an_unmerged_frame_between_merged_ones_takes_their_position_and_keeps_its_heading():
    """A walk at 1 m/s along x: frames 0, 2 and 5 merged; frame 1 (12 cm off sideways, 2 deg
    yaw of its own) lies in a 0.2 s gap and is moved onto the line, its yaw kept; frames 3-4
    lie in a 0.3 s gap, bridged with 0.31 s allowed, not with 0.25 s; frame 6, after the last merged
    frame, is not moved."""
    frames = [
        record(0.0, 0.0, 0.0, 0.0, True),
        record(0.1, 0.1, 0.12, 2.0, False),
        record(0.2, 0.2, 0.0, 0.0, True),
        record(0.3, 0.3, -0.1, 0.0, False),
        record(0.4, 0.4, 0.1, 0.0, False),
        record(0.5, 0.5, 0.0, 0.0, True),
        record(0.6, 0.6, 0.2, 0.0, False),
    ]
    out = bridge_unmerged(frames, 0.31)
    assert np.allclose(out[1].T_tls_mid[:3, 3], [0.1, 0.0, 0.0])
    assert np.allclose(out[1].T_tls_mid[:3, :3], frames[1].T_tls_mid[:3, :3])
    # The stamp pose moves with the mid-sweep pose.
    assert np.allclose(out[1].T_tls_sensor[:3, 3], [0.06, 0.0, 0.0])
    assert "bridged" in out[1].reason and not out[1].accepted
    assert np.allclose(out[3].T_tls_mid[:3, 3], [0.3, 0.0, 0.0])
    assert np.allclose(out[4].T_tls_mid[:3, 3], [0.4, 0.0, 0.0])
    assert out[6] is frames[6]
    for k in (0, 2, 5):
        assert out[k] is frames[k]
    tight = bridge_unmerged(frames, 0.25)
    assert tight[3] is frames[3] and tight[4] is frames[4]
    assert np.allclose(tight[1].T_tls_mid[:3, 3], [0.1, 0.0, 0.0])
    assert bridge_unmerged(frames, 0.0) is frames


def test_no_position_is_bridged_across_a_relocalization():
    """The tracking was lost between the merged frames 0 and 3 (frame 2 relocalized on the
    reference's stems): the walk may have jumped, so frames 1 and 2 keep their own poses."""
    frames = [
        record(0.0, 0.0, 0.0, 0.0, True),
        record(0.1, 2.0, 1.0, 0.0, False),
        record(0.2, 4.0, 2.0, 0.0, False),
        record(0.3, 4.1, 2.0, 0.0, True),
    ]
    frames[2].relocalized = True
    out = bridge_unmerged(frames, 0.5)
    assert all(a is b for a, b in zip(out, frames, strict=True))
