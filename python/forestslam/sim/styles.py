"""World styles: two independent sets of stem, crown and intensity models, so that every figure
can be printed on two worlds that do not share the project's modelling choices.

A style fills in the keys a scenario leaves unset; keys the scenario (or an override) sets win.
`a` is the configuration defaults: round-ish stems (ellipse, 2-3-5 lobes, 3 mm bark, light flare
and sweep), crowns of a few large clumps, bright foliage with a weak range fall-off. `b`: polygonal
stems (9-16 sides) with up to 10 % ovality, 5 mm bark, strong root flare reaching breast height on
some trees, more lean and sweep; many small dense leaf clumps lower on the stem; darker, more
spread intensities with a steeper range fall-off.
"""

from __future__ import annotations

import copy
from typing import Any

STYLES: dict[str, dict[str, Any]] = {
    "a": {},
    "b": {
        "stems": {
            "taper_m_per_m": 0.012,
            "max_lean_deg": 5.0,
            "max_ellipticity": 0.053,
            "bark_amplitude_m": 0.005,
            "irregularity": [0.01, 0.05],
            "polygon_sides": [9, 16],
            "flare": [0.2, 0.6],
            "flare_height_m": [0.8, 2.0],
            "max_sweep_m_per_m": 0.012,
        },
        "clutter": {
            "branches_per_tree": 6.0,
            "crown_base_fraction": [0.3, 0.55],
            "crown_radius_fraction": 0.13,
            "crown_clumps": 14,
            "foliage_sigma_per_m": 2.0,
        },
        "intensity": {
            "ground": {"median": 25.0, "sigma_return": 0.4, "incidence_exponent": 0.7},
            "bark": {
                "median": 32.0,
                "sigma_return": 0.35,
                "sigma_object": 0.25,
                "incidence_exponent": 0.7,
            },
            "branch": {"median": 40.0, "sigma_return": 0.35, "sigma_object": 0.2},
            "foliage": {"median": 120.0, "sigma_return": 0.4, "sigma_object": 0.15},
            "shrub": {"median": 95.0, "sigma_return": 0.4, "sigma_object": 0.15},
            "deadwood": {"median": 85.0, "sigma_return": 0.35, "sigma_object": 0.2},
            "reference_range_m": 8.0,
            "range_exponent": 0.5,
            "near_range_m": 2.0,
        },
    },
}


def _merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def apply_style(data: dict[str, Any]) -> dict[str, Any]:
    """The scenario mapping with its style's presets under it (the scenario's keys win)."""
    from forestslam.errors import InputError

    style = str(data.get("style", "a")).lower()
    if style not in STYLES:
        raise InputError(f"unknown world style {style!r}; choose one of {', '.join(STYLES)}")
    merged = _merge(STYLES[style], data)
    merged["style"] = style
    return merged
