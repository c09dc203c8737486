"""The simulated sensor's measurement model: range noise and dropouts per sensor, intensity per
material. These are the simulator's own truths, deliberately not the profile's nominal
`range_noise_m` / `dropout_rate` (what the pipeline assumes) nor its `intensity_threshold`.

Range noise: standard deviation `range_noise_m` at normal incidence plus, in quadrature, the
spread of the beam footprint over an inclined surface (0.5 divergence range tan(incidence), tan
capped at 10; the divergence is the beam's vertical one, which spreads ground returns).
Dropouts: `dropout_rate` everywhere, fading to total loss below |cos incidence| = `grazing_cos`
and beyond `far_fraction` of the maximum range.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from forestslam.errors import InputError
from forestslam.sensors import SensorProfile
from forestslam.sim.config import IntensityConfig, SensorConfig


@dataclass(frozen=True)
class SensorNoise:
    range_noise_m: float
    beam_divergence_mrad: float
    dropout_rate: float
    grazing_cos: float
    far_fraction: float


# Standard deviations at normal incidence after the data sheets' accuracies (VLP-16 +-3 cm,
# HDL-32E +-2 cm, OS1 +-1.5-5 cm, RS-M1 +-5 cm, phase TLS about 2 mm), vertical beam divergences
# (mrad), base dropout rates, grazing cosines and far fractions.
SENSOR_NOISE: dict[str, SensorNoise] = {
    "vlp16": SensorNoise(0.03, 1.5, 0.02, 0.1, 0.7),
    "hdl32": SensorNoise(0.02, 1.5, 0.02, 0.1, 0.7),
    "os1-64": SensorNoise(0.02, 1.5, 0.01, 0.08, 0.75),
    "rs-m1": SensorNoise(0.03, 2.0, 0.02, 0.12, 0.7),
    "tls": SensorNoise(0.002, 0.3, 0.0, 0.03, 0.9),
}

# Rows of the materials table = surface classes (forest.SURFACES).
_MATERIAL_ROWS = ("ground", "ground", "bark", "branch", "foliage", "shrub", "deadwood")


def sensor_noise(profile: SensorProfile, cfg: SensorConfig) -> SensorNoise:
    """The table's model for this profile (a profile not in it: its nominal noise and dropout
    rate with a 2 mrad beam), with the values set in the scenario's sensor section on top."""
    base = SENSOR_NOISE.get(
        profile.name, SensorNoise(profile.range_noise_m, 2.0, profile.dropout_rate, 0.1, 0.8)
    )
    over = {
        k: float(getattr(cfg, k))
        for k in ("range_noise_m", "beam_divergence_mrad", "dropout_rate", "grazing_cos")
        if getattr(cfg, k) is not None
    }
    if cfg.far_fraction is not None:
        over["far_fraction"] = float(cfg.far_fraction)
    noise = replace(base, **over)
    checks = (
        (noise.range_noise_m >= 0, "range_noise_m >= 0"),
        (noise.beam_divergence_mrad >= 0, "beam_divergence_mrad >= 0"),
        (0 <= noise.dropout_rate < 1, "0 <= dropout_rate < 1"),
        (0 <= noise.grazing_cos < 1, "0 <= grazing_cos < 1"),
        (0 < noise.far_fraction <= 1, "0 < far_fraction <= 1"),
    )
    bad = [what for ok, what in checks if not ok]
    if bad:
        raise InputError(f"sensor: need {', '.join(bad)}")
    return noise


def scan_model(
    profile: SensorProfile, noise: SensorNoise, intensity: IntensityConfig, object_seed: int
) -> Any:
    """The C++ measurement model (``forestslam._core.ScanModel``): ranges, noise, dropouts and the
    (7,4) materials table (median, sigma_return, sigma_object, incidence_exponent per surface
    class)."""
    from forestslam.core_bridge import core_struct

    rows = []
    for name in _MATERIAL_ROWS:
        m = getattr(intensity, name)
        if not (m.median >= 0 and m.sigma_return >= 0 and m.sigma_object >= 0):
            raise InputError(f"intensity.{name}: need median, sigma_return, sigma_object >= 0")
        rows.append([m.median, m.sigma_return, m.sigma_object, m.incidence_exponent])
    if not (intensity.reference_range_m > 0 and intensity.near_range_m >= 0):
        raise InputError("intensity: need reference_range_m > 0 and near_range_m >= 0")
    values = {
        "range_min_m": float(profile.range_min_m),
        "range_max_m": float(profile.range_max_m),
        "range_noise_m": float(noise.range_noise_m),
        "beam_divergence_rad": noise.beam_divergence_mrad * 1e-3,
        "dropout_rate": float(noise.dropout_rate),
        "grazing_cos": float(noise.grazing_cos),
        "far_fraction": float(noise.far_fraction),
        "reference_range_m": float(intensity.reference_range_m),
        "range_exponent": float(intensity.range_exponent),
        "near_range_m": float(intensity.near_range_m),
        "object_seed": int(object_seed) % (2**63),
        "materials": np.ascontiguousarray(rows, dtype=np.float64),
    }
    return core_struct("ScanModel", values, "scan model")
