"""One config bridge (issue 18): every Python config dataclass that crosses into the C++ core has
the fields of its typed C++ struct with the same defaults, and the bridge refuses unknown keys and
wrong types with the key named."""

from __future__ import annotations

import dataclasses
import math

import pytest

from forestslam.errors import InputError

_core = pytest.importorskip("forestslam._core")

# Fields that exist on one side only, on purpose.
ONLY_PYTHON = {"PerceptionConfig": {"intensity_filter"}}  # decides intensity_threshold
ONLY_CPP = {
    "FpfhConfig": {"icp"},  # the odometry's registration.icp is used
    # from the sensor profile / from detect's breast_height_z argument
    "PerceptionConfig": {"intensity_threshold", "breast_height_z"},
}


def _pairs():
    from forestslam.odometry import OdometryConfig
    from forestslam.perception.config import PerceptionConfig
    from forestslam.registration import (
        FpfhConfig,
        IcpConfig,
        RegistrationConfig,
        ShapeConfig,
        TreeMatchConfig,
    )

    return [
        (OdometryConfig, _core.OdometryConfig),
        (RegistrationConfig, _core.RegistrationConfig),
        (TreeMatchConfig, _core.TreeMatchConfig),
        (ShapeConfig, _core.ShapeRegistrationConfig),
        (IcpConfig, _core.IcpConfig),
        (FpfhConfig, _core.FpfhConfig),
        (PerceptionConfig, _core.PerceptionConfig),
    ]


def _cpp_fields(obj) -> set[str]:
    return {k for k, v in vars(type(obj)).items() if isinstance(v, property)}


def _compare(py, cpp, where: str) -> list[str]:
    """Differences (names and defaults) between a dataclass instance and a pybind struct."""
    diffs = []
    py_names = {f.name for f in dataclasses.fields(py)} - ONLY_PYTHON.get(type(py).__name__, set())
    cpp_names = _cpp_fields(cpp) - ONLY_CPP.get(type(cpp).__name__, set())
    diffs += [f"{where}.{n}: only in Python" for n in sorted(py_names - cpp_names)]
    diffs += [f"{where}.{n}: only in C++" for n in sorted(cpp_names - py_names)]
    for name in sorted(py_names & cpp_names):
        a, b = getattr(py, name), getattr(cpp, name)
        if dataclasses.is_dataclass(a):
            diffs += _compare(a, b, f"{where}.{name}")
        elif isinstance(a, float) and isinstance(b, float):
            if not math.isclose(a, b, rel_tol=1e-12):
                diffs.append(f"{where}.{name}: Python {a!r}, C++ {b!r}")
        elif a != b or type(a) is not type(b):
            diffs.append(f"{where}.{name}: Python {a!r}, C++ {b!r}")
    return diffs


@pytest.mark.parametrize("py_cls, cpp_cls", _pairs(), ids=lambda c: c.__name__)
def test_every_default_agrees(py_cls, cpp_cls):
    assert _compare(py_cls(), cpp_cls(), py_cls.__name__) == []


def test_bridge_names_unknown_keys_and_wrong_types():
    from forestslam.odometry import OdometryConfig
    from forestslam.odometry.bridge import fill_core
    from forestslam.odometry.odometry import core_odometry_config

    @dataclasses.dataclass
    class Extra:
        banana: int = 1

    with pytest.raises(InputError, match=r"x\.banana"):
        fill_core(Extra(), _core.TreeMatchConfig(), "x")
    bad = OdometryConfig()
    bad.map_voxel_m = True  # YAML "true" must not become 1 m
    with pytest.raises(InputError, match=r"odometry\.map_voxel_m"):
        core_odometry_config(bad)
    bad = OdometryConfig()
    bad.registration.icp.max_iterations = "12"
    with pytest.raises(InputError, match=r"odometry\.registration\.icp\.max_iterations"):
        core_odometry_config(bad)
    bad = OdometryConfig()
    bad.registration.icp.max_iterations = 0
    with pytest.raises(InputError, match="max_iterations"):
        core_odometry_config(bad)
    ok = core_odometry_config(OdometryConfig(keyframe_distance_m=2, max_stamp_gap_s=0.5))
    assert ok.keyframe_distance_m == 2.0 and ok.max_stamp_gap_s == 0.5


def test_perception_options_cross_typed_with_the_key_named():
    """detect and every perception stage take the typed C++ structs from the one bridge."""
    import math

    from forestslam.perception.config import PerceptionConfig
    from forestslam.perception.pipeline import core_options, segment_ground, sensor_geometry
    from forestslam.sensors import load_profile

    profile = load_profile("vlp16")
    options = core_options(PerceptionConfig(), profile, breast_height_z=1.5)
    assert isinstance(options, _core.PerceptionConfig) and options.breast_height_z == 1.5
    assert math.isnan(core_options(PerceptionConfig(), profile).breast_height_z)
    assert isinstance(sensor_geometry(profile), _core.SensorGeometry)
    bad = PerceptionConfig()
    bad.ground.cell_size_m = "0.5"
    with pytest.raises(InputError, match=r"perception\.ground\.cell_size_m"):
        core_options(bad, profile)
    with pytest.raises(InputError, match=r"perception\.ground\.cell_size_m"):
        segment_ground([[0.0, 0.0, 0.0]], bad)
