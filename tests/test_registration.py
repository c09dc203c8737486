"""Registration facade (forestslam.registration) on synthetic stems and scenes with known poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forestslam.errors import InputError

reg = pytest.importorskip("forestslam.registration")
pytest.importorskip("forestslam._core")


def planar(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T[:2, 3] = x, y
    return T


def rot_err_deg(A: np.ndarray, B: np.ndarray) -> float:
    R = A[:3, :3].T @ B[:3, :3]
    return math.degrees(math.acos(np.clip((np.trace(R) - 1) / 2, -1, 1)))


def stems(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    while len(out) < n:
        p = rng.uniform(-15, 15, 2)
        if np.linalg.norm(p) > 2 and all(np.linalg.norm(p - q) > 2 for q in out):
            out.append(p)
    return np.array(out)


def scene(xy: np.ndarray, seed: int, noise: float = 0.0) -> np.ndarray:
    """Stem cylinders (r 0.15 m, 0.2-4 m above ground) and a sloped ground grid."""
    rng = np.random.default_rng(seed)
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    z = np.arange(0.2, 4.0, 0.1)
    ring = np.column_stack([0.15 * np.cos(a), 0.15 * np.sin(a)])
    parts = []
    for c in xy:
        zz, k = np.meshgrid(z, np.arange(len(a)), indexing="ij")
        p = np.column_stack([c + ring[k.ravel()], zz.ravel() - 1.5 + 0.05 * c[0]])
        parts.append(p)
    g = np.mgrid[-16:16:0.5, -16:16:0.5].reshape(2, -1).T
    parts.append(np.column_stack([g, -1.5 + 0.05 * g[:, 0] - 0.02 * g[:, 1]]))
    cloud = np.concatenate(parts)
    return cloud + rng.normal(scale=noise, size=cloud.shape) if noise else cloud


def move(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(p @ T[:3, :3].T + T[:3, 3])


def gaussians(xy: np.ndarray, yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    means = np.column_stack([xy, np.full(len(xy), 1.3)])
    c = np.diag([0.015, 0.01, 1.2])
    R = planar(0, 0, yaw)[:3, :3]
    return means, np.repeat((R @ c @ R.T)[None], len(xy), axis=0)


def test_shape_registration_recovers_pose_despite_wrong_pairs():
    T = planar(0.9, -0.4, 0.12)
    tgt_xy = stems(12, 1)
    tgt_m, tgt_c = gaussians(tgt_xy)
    src_m, src_c = gaussians(move(np.linalg.inv(T), tgt_m)[:, :2], -0.12)
    pairs = reg.match_trees(src_m, tgt_m, planar(0.7, -0.3, 0.1))
    assert len(pairs) >= 10
    pairs = np.array(pairs)
    pairs[:2, 1] = pairs[[1, 0], 1]  # two wrong pairs
    r = reg.register_shapes(src_m, src_c, tgt_m, tgt_c, pairs, planar(0.7, -0.3, 0.1))
    est = np.asarray(r.T_target_source)
    assert np.linalg.norm(est[:2, 3] - T[:2, 3]) < 0.01
    assert rot_err_deg(est, T) < 0.1
    assert r.inliers == len(pairs) - 2
    assert not r.degenerate
    assert r.covariance.shape == (6, 6) and 0 < r.covariance[0, 0] < 0.01


@pytest.mark.parametrize("n", [0, 1, 2])
def test_two_or_fewer_stems_are_degenerate(n):
    tgt_m, tgt_c = gaussians(stems(max(n, 1), 3))
    pairs = np.column_stack([np.arange(n), np.arange(n)])
    r = reg.register_shapes(tgt_m, tgt_c, tgt_m, tgt_c, pairs, np.eye(4))
    assert r.degenerate


def test_icp_recovers_scan_against_itself_moved():
    T = np.eye(4)
    a, b = 0.06, 0.02
    T[:3, :3] = np.array(
        [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
    ) @ np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    T[:3, 3] = [0.3, -0.25, 0.04]
    target = scene(stems(15, 4), 5)
    source = move(np.linalg.inv(T), target)
    r = reg.icp_point_to_plane(reg.PlaneTarget(target), source, np.eye(4))
    est = np.asarray(r.T_target_source)
    assert np.linalg.norm(est[:3, 3] - T[:3, 3]) < 0.01
    assert rot_err_deg(est, T) < 0.1
    assert r.converged and not r.degenerate


def test_fpfh_baseline_recovers_transform_without_guess():
    T = planar(1.2, 0.5, 0.4)
    target = scene(stems(20, 6), 7, noise=0.005)
    source = move(np.linalg.inv(T), scene(stems(20, 6), 8, noise=0.005))
    r = reg.register_fpfh(source, target)
    est = np.asarray(r.T_target_source)
    assert np.linalg.norm(est[:3, 3] - T[:3, 3]) < 0.05
    assert rot_err_deg(est, T) < 0.5
    assert r.inliers > 10


def test_bad_inputs_raise_input_error_and_empty_inputs_do_not_crash():
    with pytest.raises(InputError):
        reg.match_trees(np.zeros((3, 2)), np.zeros((3, 3)), np.eye(4))
    with pytest.raises(InputError):
        reg.icp_point_to_plane(reg.PlaneTarget(np.zeros((0, 3))), np.zeros((5, 3)), np.eye(3))
    m, c = gaussians(stems(3, 1))
    with pytest.raises(InputError):
        reg.register_shapes(m, c[:2], m, c, np.zeros((0, 2)), np.eye(4))
    r = reg.icp_point_to_plane(reg.PlaneTarget(np.zeros((0, 3))), np.zeros((0, 3)), np.eye(4))
    assert not r.converged and r.degenerate
    nan = np.full((4, 3), np.nan)
    assert len(reg.match_trees(nan, nan, np.eye(4))) == 0
    assert len(reg.voxel_downsample(nan, 0.25)) == 0


def test_poses_cross_the_binding_as_rigid_4x4_arrays():
    core = pytest.importorskip("forestslam._core")
    m, c = gaussians(stems(3, 1))
    T = planar(1.0, 2.0, 0.3)
    # Without pairs the result keeps the (planar) initial pose: a pose into C++ and back.
    r = reg.register_shapes(m, c, m, c, np.zeros((0, 2)), T)
    assert r.T_target_source.shape == (4, 4) and r.T_target_source.dtype == np.float64
    np.testing.assert_allclose(r.T_target_source, T, atol=1e-15)
    sheared = np.eye(4)
    sheared[3, 0] = 0.5  # a projective matrix, not a pose
    with pytest.raises(ValueError, match="last row"):
        core.transform_points(sheared, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="gate_m"):
        core.match_trees(np.zeros((2, 3)), np.zeros((2, 3)), np.eye(4), 0.0)


def test_registration_results_are_read_only():
    core = pytest.importorskip("forestslam._core")
    m, c = gaussians(stems(6, 2))
    r = reg.register_shapes(m, c, m, c, np.array([[k, k] for k in range(6)]), np.eye(4))
    assert r.converged and r.inliers == 6
    fields = ("T_target_source", "covariance", "converged", "degenerate", "inliers", "iterations")
    for name in (*fields, "rmse"):
        with pytest.raises(AttributeError):
            setattr(r, name, getattr(r, name))
    with pytest.raises(ValueError, match="read-only"):
        r.covariance[0, 0] = 0.0
    with pytest.raises(TypeError):
        core.RegistrationResult()  # made by the registrations only
