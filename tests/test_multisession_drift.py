"""Drift injection (multisession.drift): the heading error turns about the world vertical, so
a tilted sensor keeps its true tilt and the drifted rotation stays a rotation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from forestslam.multisession.drift import DriftInjector


def test_tilted_walk_keeps_its_tilt_and_drifts_in_heading_only():
    rng = np.random.default_rng(5)
    drift = DriftInjector(0.02, 1.0)
    heading = 0.0
    for k in range(400):  # 800 m: 80 deg of injected heading error
        heading += rng.normal(0, 0.05)
        tilt = np.radians(rng.uniform(5, 20)) * np.r_[rng.normal(size=2), 0]
        T = np.eye(4)
        T[:3, :3] = (Rotation.from_euler("z", heading) * Rotation.from_rotvec(tilt)).as_matrix()
        T[:2, 3] = [2.0 * k, 0.0]
        D = drift.apply(T)
        R_err = D[:3, :3] @ T[:3, :3].T  # drifted = Rz(a) true
        assert np.allclose(D[:3, :3] @ D[:3, :3].T, np.eye(3), atol=1e-9)
        assert np.allclose(R_err[:, 2], [0, 0, 1], atol=1e-9)
    # 1 deg per 10 m of the step as the sensor measures it (tilted: a little under 800 m)
    assert 74.0 < np.degrees(np.arctan2(R_err[1, 0], R_err[0, 0])) < 80.0
