"""Python facade over forestslam._core registration: validates shapes; configs cross into C++
through forestslam.core_bridge (the typed C++ structs, defaults kept in C++)."""

from __future__ import annotations

from typing import Any

import numpy as np

from forestslam.errors import InputError
from forestslam.registration.config import FpfhConfig, IcpConfig, ShapeConfig, TreeMatchConfig


def _core():
    from forestslam import _core

    return _core


def _points(a: Any, name: str) -> np.ndarray:
    p = np.ascontiguousarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{name} must have shape (N,3), got {p.shape}")
    return p


def _pose(T: Any, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(f"{name} must be a finite (4,4) pose, got shape {T.shape}")
    return T


def _to_core(config: Any, core_cls: Any, where: str) -> Any:
    from forestslam.core_bridge import fill_core

    return fill_core(config, core_cls(), where)


def core_icp_config(config: IcpConfig) -> Any:
    return _to_core(config, _core().IcpConfig, "icp")


def match_trees(
    source: np.ndarray,
    target: np.ndarray,
    T_target_source_predicted: np.ndarray,
    config: TreeMatchConfig | None = None,
) -> np.ndarray:
    """Stem pairs (P,2) int (source index, target index): mutual nearest in XY within the gate,
    source (K,3) moved by the predicted pose (4,4) first; target (M,3)."""
    c = config or TreeMatchConfig()
    return np.asarray(
        _core().match_trees(
            _points(source, "source"),
            _points(target, "target"),
            _pose(T_target_source_predicted, "T_target_source_predicted"),
            c.gate_m,
            c.ratio,
        ),
        dtype=np.int64,
    ).reshape(-1, 2)


def register_shapes(
    source_means: np.ndarray,
    source_covs: np.ndarray,
    target_means: np.ndarray,
    target_covs: np.ndarray,
    pairs: np.ndarray,
    T_init: np.ndarray,
    config: ShapeConfig | None = None,
) -> Any:
    """Shape-to-shape registration over x, y, yaw. means (K,3), covs (K,3,3), pairs (P,2)."""
    sm, tm = _points(source_means, "source_means"), _points(target_means, "target_means")
    sc = np.ascontiguousarray(source_covs, dtype=np.float64).reshape(-1, 9)
    tc = np.ascontiguousarray(target_covs, dtype=np.float64).reshape(-1, 9)
    if len(sc) != len(sm) or len(tc) != len(tm):
        raise InputError("one 3x3 covariance per stem mean is required")
    p = np.ascontiguousarray(pairs, dtype=np.int32).reshape(-1, 2)
    cfg = _to_core(config or ShapeConfig(), _core().ShapeRegistrationConfig, "shape")
    return _core().register_shapes(sm, sc, tm, tc, p, _pose(T_init, "T_init"), cfg)


def PlaneTarget(points: np.ndarray, normal_k: int = 10) -> Any:  # noqa: N802 (a constructor)
    """ICP target (KD-tree + PCA normals) over points (M,3); build once, reuse for many scans."""
    return _core().PlaneTarget(_points(points, "target points"), int(normal_k))


def icp_point_to_plane(
    target: Any,
    source: np.ndarray,
    T_init: np.ndarray,
    config: IcpConfig | None = None,
    prior_information: np.ndarray | None = None,
    T_prior: np.ndarray | None = None,
) -> Any:
    """Point-to-plane ICP of source (N,3) onto a PlaneTarget from T_init (4,4); an optional (6,6)
    prior information pulls towards T_prior (default T_init) in (tx,ty,tz,rx,ry,rz)."""
    info = np.zeros((6, 6)) if prior_information is None else np.asarray(prior_information, float)
    T0 = _pose(T_init, "T_init")
    Tp = T0 if T_prior is None else _pose(T_prior, "T_prior")
    return _core().icp_point_to_plane(
        target, _points(source, "source"), T0, core_icp_config(config or IcpConfig()), info, Tp
    )


def register_fpfh(
    source: np.ndarray,
    target: np.ndarray,
    T_init: np.ndarray | None = None,
    config: FpfhConfig | None = None,
    icp: IcpConfig | None = None,
) -> Any:
    """FPFH + RANSAC + point-to-plane ICP of source (N,3) onto target (M,3)."""
    cfg = _to_core(config or FpfhConfig(), _core().FpfhConfig, "fpfh")
    cfg.icp = core_icp_config(icp or IcpConfig())
    T0 = np.eye(4) if T_init is None else _pose(T_init, "T_init")
    return _core().register_fpfh(_points(source, "source"), _points(target, "target"), T0, cfg)


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Voxel-grid centroids of points (N,3) -> (M,3)."""
    return np.asarray(_core().voxel_centroids(_points(points, "points"), float(voxel_m)))
