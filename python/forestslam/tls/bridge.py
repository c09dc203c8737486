"""TLS config into the typed C++ structs, through the one bridge (forestslam.core_bridge).

A TLS config section feeds several C++ structs, so its fields carry a prefix (``lm_*`` onto
StemCentreLmConfig, ``ndt_*`` onto NdtConfig) or appear in the name maps below; the rest of a
section is Python-only. Every C++ field not set here keeps its C++ default; a value known only
at the call (a round count, a height band) is an override by its C++ field name, checked like
the rest. tests/test_config_parity.py checks the names and that the TLS defaults equal the C++
ones where they are not tuned for the TLS on purpose.
"""

from __future__ import annotations

from typing import Any

from forestslam.core_bridge import core_struct, prefixed, renamed
from forestslam.tls.config import FeatureConfig, RegistrationConfig

LM_FIELDS = prefixed(RegistrationConfig, "lm_")
NDT_FIELDS = prefixed(RegistrationConfig, "ndt_")
KEYPOINT_FIELDS = {
    "keypoint_voxel_m": "voxel_m",
    "sigma_small_m": "sigma_small_m",
    "sigma_large_m": "sigma_large_m",
    "nms_radius_m": "nms_radius_m",
    "max_keypoints": "max_keypoints",
}
VIRTUAL_FIELDS = {"min_diameter_m": "min_diameter_m", "max_diameter_m": "max_diameter_m"}
MOTION_FIELDS = {"max_velocity_age_s": "max_gap_s"}


def lm_config(reg: RegistrationConfig, **overrides: Any) -> Any:
    """``_core.StemCentreLmConfig`` of the ``lm_*`` fields, then `overrides`."""
    return core_struct(
        "StemCentreLmConfig", {**renamed(reg, LM_FIELDS), **overrides}, "tls.registration"
    )


def ndt_config(reg: RegistrationConfig) -> Any:
    """``_core.NdtConfig`` of the ``ndt_*`` fields."""
    return core_struct("NdtConfig", renamed(reg, NDT_FIELDS), "tls.registration")


def motion_model_config(reg: RegistrationConfig) -> Any:
    """``_core.MotionModelConfig``: the velocity is forgotten after max_velocity_age_s."""
    return core_struct("MotionModelConfig", renamed(reg, MOTION_FIELDS), "tls.registration")


def keypoint_config(features: FeatureConfig) -> Any:
    """``_core.DogKeypointsConfig`` of the DoG keypoint fields of `features`."""
    return core_struct("DogKeypointsConfig", renamed(features, KEYPOINT_FIELDS), "tls.features")


def virtual_feature_config(features: FeatureConfig, **overrides: Any) -> Any:
    """``_core.VirtualFeaturesConfig`` of the stem-diameter bounds of `features`, then
    `overrides` (e.g. a height band min_z_m / max_z_m, circle-fit gates)."""
    values = {**renamed(features, VIRTUAL_FIELDS), **overrides}
    return core_struct("VirtualFeaturesConfig", values, "tls.features")
