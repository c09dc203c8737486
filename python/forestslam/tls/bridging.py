"""Positions of frames that did not join the map, bridged from the merged frames around them.

A frame that does not join the map failed the merge's checks (its stem pairs too loose, its
pose not holding on the reference alone, its LM not trusted, ...): its own pose is not
verified. On the bench plots such frames sat 10-15 cm off while the merged frames on either
side were within 3-5 cm (spruce-line-far, 22-24 m from the station: the walk and the station
see opposite sides of the stems in between, and one-sided stem fits pull the LM). Over a short
gap a walking scanner's position changes smoothly, while its orientation does not (vibration
shakes roll and pitch from frame to frame), so such a frame keeps its own orientation and takes
its position from the merged frames before and after it, linear in time. Frames outside a gap
(before the first merged frame, after the last, or in a longer gap) keep their own pose, and so
do the frames of a gap in which the tracking was lost (a frame relocalized on the reference's
stems: the walk may have jumped, e.g. frames dropped by the recorder).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from forestslam.tls.pipeline import FrameRecord


def bridge_unmerged(frames: list[FrameRecord], max_gap_s: float) -> list[FrameRecord]:
    """The records with every frame that did not join the map, lying between two merged frames
    at most max_gap_s apart (registration times) with no relocalized frame between them, moved
    to the position interpolated between them; the rest unchanged. 0 turns it off."""
    if max_gap_s <= 0 or len(frames) < 3:
        return frames
    t = np.array([f.stamp + f.t_mid_s for f in frames])
    merged = np.flatnonzero([f.accepted for f in frames])
    out = list(frames)
    for i in np.flatnonzero([not f.accepted for f in frames]):
        k = int(np.searchsorted(merged, i))
        if k == 0 or k == len(merged):
            continue
        a, b = merged[k - 1], merged[k]
        if t[b] - t[a] > max_gap_s or any(f.relocalized for f in frames[a : b + 1]):
            continue
        w = (t[i] - t[a]) / (t[b] - t[a])
        p = (1 - w) * frames[a].T_tls_mid[:3, 3] + w * frames[b].T_tls_mid[:3, 3]
        out[i] = _moved(frames[i], p - frames[i].T_tls_mid[:3, 3])
    return out


def _moved(record: FrameRecord, shift: np.ndarray) -> FrameRecord:
    """The record with its poses (mid-sweep and stamp) shifted by shift (3,) in the TLS frame,
    its reason noting the bridge."""
    T_mid, T_stamp = record.T_tls_mid.copy(), record.T_tls_sensor.copy()
    T_mid[:3, 3] += shift
    T_stamp[:3, 3] += shift
    reason = f"{record.reason}; position bridged from the merged frames around it"
    return dataclasses.replace(record, T_tls_mid=T_mid, T_tls_sensor=T_stamp, reason=reason)
