"""One config bridge (issue 18): every Python config dataclass that crosses into the C++ core has
the fields of its typed C++ struct with the same defaults, and the bridge refuses unknown keys and
wrong types with the key named."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from forestslam.errors import InputError

_core = pytest.importorskip("forestslam._core")

# Fields that exist on one side only, on purpose.
ONLY_PYTHON = {
    "PerceptionConfig": {"intensity_filter"},  # decides intensity_threshold
    # matcher: a name (C++: an enum); distinct_yaw_deg: C++ distinct_yaw_rad; the rest
    # aggregates frames into a query (Python only)
    "LocalizationConfig": {
        "matcher",
        "distinct_yaw_deg",
        "merge_radius_m",
        "keyframe_distance_m",
        "min_observations",
        "max_range_m",
        "retry_frames",
        "retry_last_frames",
        "retry_keyframe_distance_m",
    },
}
ONLY_CPP = {
    "FpfhConfig": {"icp"},  # the odometry's registration.icp is used
    # from the sensor profile / from detect's breast_height_z argument
    "PerceptionConfig": {"intensity_threshold", "breast_height_z"},
    # paper-matcher bins: fixed by the paper, not configurable
    "GlobalLocalizerConfig": {
        "matcher",
        "distinct_yaw_rad",
        "paper_angle_bin_rad",
        "paper_translation_bin_m",
    },
}


def _pairs():
    from forestslam.localization.config import LocalizationConfig
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
        (LocalizationConfig, _core.GlobalLocalizerConfig),
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
    from forestslam.core_bridge import fill_core
    from forestslam.odometry import OdometryConfig
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


def test_localization_yaw_in_degrees_matches_the_cpp_radians():
    from forestslam.localization.config import LocalizationConfig

    rad = _core.GlobalLocalizerConfig().distinct_yaw_rad
    # the C++ default is the literal 0.0873 (5 deg written to 4 decimals)
    assert math.isclose(math.radians(LocalizationConfig().distinct_yaw_deg), rad, abs_tol=5e-5)


# TLS sections feed several C++ structs through name maps (forestslam.tls.bridge); these TLS
# defaults differ from the C++ ones on purpose (the TLS LM stops earlier: sub-mm rounds do not
# change a plot map at 3 cm voxels).
# max_velocity_age_s: a TLS walk forgets its velocity sooner than the odometry's stamp gap.
TLS_TUNED = {"lm_converged_translation_m", "lm_converged_rotation_rad", "max_velocity_age_s"}


def _tls_maps():
    from forestslam.tls import bridge
    from forestslam.tls.config import FeatureConfig, RegistrationConfig

    return [
        (RegistrationConfig, bridge.LM_FIELDS, _core.StemCentreLmConfig),
        (RegistrationConfig, bridge.NDT_FIELDS, _core.NdtConfig),
        (RegistrationConfig, bridge.MOTION_FIELDS, _core.MotionModelConfig),
        (FeatureConfig, bridge.KEYPOINT_FIELDS, _core.DogKeypointsConfig),
        (FeatureConfig, bridge.VIRTUAL_FIELDS, _core.VirtualFeaturesConfig),
    ]


def _name(c) -> str:
    return getattr(c, "__name__", "")


@pytest.mark.parametrize("py_cls, names, cpp_cls", _tls_maps(), ids=_name)
def test_tls_fields_reach_cpp_fields_with_the_cpp_defaults(py_cls, names, cpp_cls):
    py, cpp = py_cls(), cpp_cls()
    assert names, "a TLS name map is empty"
    cpp_names = _cpp_fields(cpp)
    assert set(names.values()) <= cpp_names
    for py_name, cpp_name in names.items():
        if py_name not in TLS_TUNED:
            assert math.isclose(getattr(py, py_name), getattr(cpp, cpp_name)), py_name


# Bound structs filled from something other than a config dataclass of the same shape.
FILLED_ELSEWHERE = {
    "SensorGeometry": "perception.pipeline.sensor_geometry (the sensor profile)",
    "OdometrySensor": "odometry (the sensor profile)",
    "ScanModel": "sim.sensor_model.scan_model (core_struct)",
    "TrunkExtractionConfig": "localization.localize.extract_trunks (keyword options)",
    "CircleFitConfig": "core_struct at the call: mapping.tree_map.fit_band_circle, tls.trees",
}


def test_every_bound_config_struct_has_one_declared_bridge():
    """A new option struct bound in C++ must be mirrored by a dataclass, reached by a TLS name
    map or declared above; otherwise nothing checks its defaults."""
    bound = {n for n in dir(_core) if n.endswith(("Config", "Sensor", "Geometry", "ScanModel"))}
    mirrored = {c.__name__ for _, c in _pairs()}
    # nested in PerceptionConfig, compared field by field with it
    mirrored |= {"GroundConfig", "NormalFilterConfig", "SegmentationConfig", "DiameterConfig"}
    mapped = {c.__name__ for _, _, c in _tls_maps()}
    assert bound - mirrored - mapped - set(FILLED_ELSEWHERE) == set()
    assert set(FILLED_ELSEWHERE) <= bound


def test_tls_bridge_builds_typed_structs_and_names_bad_keys():
    from forestslam.tls.bridge import lm_config, ndt_config, virtual_feature_config
    from forestslam.tls.config import FeatureConfig, RegistrationConfig

    reg = RegistrationConfig(lm_virtual_gate_m=0.2, ndt_voxel_m=0.4)
    lm = lm_config(reg, max_rounds=4, sweep_order=2)
    assert isinstance(lm, _core.StemCentreLmConfig)
    assert (lm.virtual_gate_m, lm.max_rounds, lm.sweep_order) == (0.2, 4, 2)
    assert lm.converged_translation_m == reg.lm_converged_translation_m
    assert ndt_config(reg).voxel_m == 0.4
    with pytest.raises(InputError, match=r"tls\.registration\.max_round\b"):
        lm_config(reg, max_round=4)
    with pytest.raises(InputError, match=r"tls\.features\.min_z_m"):
        virtual_feature_config(FeatureConfig(), min_z_m="low")
    with pytest.raises(InputError, match=r"sweep_order"):
        lm_config(reg, sweep_order=2.5)


def test_sim_scan_model_is_typed_and_checked():
    from forestslam.core_bridge import set_field
    from forestslam.sensors import load_profile
    from forestslam.sim.config import IntensityConfig
    from forestslam.sim.sensor_model import SensorNoise, scan_model

    noise = SensorNoise(0.01, 3.0, 0.0, 0.1, 1.0)
    model = scan_model(load_profile("vlp16"), noise, IntensityConfig(), 7)
    assert isinstance(model, _core.ScanModel) and model.object_seed == 7
    assert model.materials.shape == (7, 4) and model.beam_divergence_rad == pytest.approx(3e-3)
    with pytest.raises(InputError, match=r"scan model\.materials"):
        set_field(model, "materials", np.ones((2, 4)), "scan model")
    with pytest.raises(InputError, match=r"scan model\.object_seed"):
        set_field(model, "object_seed", 1.5, "scan model")


def test_circle_fit_options_cross_typed_from_their_configs():
    """The tree map's and the TLS band fits' circle options: typed, from their own configs."""
    from forestslam.mapping.config import MappingConfig
    from forestslam.mapping.tree_map import fit_band_circle
    from forestslam.tls.config import FeatureConfig
    from forestslam.tls.trees import _circle_config

    features = FeatureConfig(min_diameter_m=0.1, max_diameter_m=0.8)
    c = _circle_config(features)
    assert isinstance(c, _core.CircleFitConfig)
    assert (c.inlier_threshold_m, c.min_radius_m, c.max_radius_m) == (0.02, 0.05, 0.4)
    assert c.seed == _core.CircleFitConfig().seed  # the rest keeps the C++ defaults
    bad = MappingConfig()
    bad.circle_inlier_m = "3 cm"
    with pytest.raises(InputError, match=r"mapping\.inlier_threshold_m"):
        fit_band_circle(np.zeros((50, 2)), bad)
