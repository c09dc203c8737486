"""The constant-velocity motion model bound for Python (forestslam._core.ConstantVelocityModel),
for pipelines that run their own registration (TLS): prediction, deskew, restarts, trust."""

from __future__ import annotations

import numpy as np
import pytest

_core = pytest.importorskip("forestslam._core")


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_predicts_and_deskews_at_constant_velocity():
    m = _core.ConstantVelocityModel()
    np.testing.assert_allclose(m.predict(0.0), np.eye(4))
    m.update(0.0, _pose(0.0))
    m.update(0.1, _pose(0.1))
    assert not m.begin_scan(0.2).restarted
    np.testing.assert_allclose(m.predict(0.2)[0, 3], 0.2, atol=1e-12)
    np.testing.assert_allclose(m.twist, [1, 0, 0, 0, 0, 0], atol=1e-12)
    out = m.deskew(np.zeros((2, 3)), np.array([0.05, -0.05]))
    np.testing.assert_allclose(out[:, 0], [0.05, -0.05], atol=1e-12)
    with pytest.raises(ValueError):
        m.deskew(np.zeros((2, 3)), np.zeros(3))


def test_gap_above_the_limit_restarts():
    cfg = _core.MotionModelConfig()
    assert cfg.max_gap_s == 1.0
    cfg.max_gap_s = 0.5
    m = _core.ConstantVelocityModel(cfg)
    m.update(0.0, _pose(0.0))
    m.update(0.1, _pose(0.1))
    check = m.begin_scan(120.1)
    assert check.restarted and check.gap_s == pytest.approx(120.0)
    np.testing.assert_allclose(m.predict(120.1)[0, 3], 0.1, atol=1e-12)  # not 120 m on
    assert m.begin_scan(50.0).restarted  # back in time


def test_untrusted_pose_is_not_kept():
    m = _core.ConstantVelocityModel()
    m.update(0.0, _pose(0.0))
    m.update(0.1, _pose(0.1))
    m.update(0.2, _pose(9.0), trusted=False)
    np.testing.assert_allclose(m.predict(0.3)[0, 3], 0.3, atol=1e-12)
    np.testing.assert_allclose(m.pose, _pose(0.1))


def test_twist_round_trip():
    xi = np.array([0.3, -0.1, 0.02, 0.01, -0.02, 0.15])
    np.testing.assert_allclose(_core.pose_to_twist(_core.twist_to_pose(xi)), xi, atol=1e-12)
