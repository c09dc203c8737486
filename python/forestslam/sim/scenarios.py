"""Named scenarios (YAML shipped in forestslam/sim/scenarios/) and overrides on top of them."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from forestslam.config_utils import from_dict, to_dict
from forestslam.errors import InputError
from forestslam.sim.config import SimConfig
from forestslam.sim.styles import apply_style

# Short override names (CLI flags, simulate(**overrides)) -> dotted config keys.
ALIASES = {
    "stand": "stand.source",
    "crop_m": "stand.crop_m",
    "sensor": "sensor.profile",
    "path": "motion.path",
    "length_m": "motion.length_m",
    "speed": "motion.speed_mps",
    "speed_mps": "motion.speed_mps",
    "height_m": "motion.sensor_height_m",
    "sensor_height_m": "motion.sensor_height_m",
    "duration_s": "motion.duration_s",
    "max_scans": "motion.max_scans",
    "format": "output.format",
    "preview": "output.preview",
    "seed": "seed",
    "style": "style",
    "name": "name",
}


def available_scenarios() -> list[str]:
    folder = resources.files("forestslam.sim") / "scenarios"
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def scenario_dict(name_or_path: str | Path | None) -> dict[str, Any]:
    """The raw mapping of a named scenario or a YAML file ({} for None)."""
    if name_or_path is None:
        return {}
    text = str(name_or_path)
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise InputError(f"{path}: scenario file not found")
        source, raw = str(path), path.read_text()
    else:
        if text not in available_scenarios():
            raise InputError(
                f"unknown scenario {text!r}; shipped: {', '.join(available_scenarios())}"
                " (or give a scenario YAML file)"
            )
        source = text
        raw = (resources.files("forestslam.sim") / "scenarios" / f"{text}.yaml").read_text()
    try:
        data = yaml.safe_load(raw) or {}
    except yaml.YAMLError as exc:
        raise InputError(f"{source}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(f"{source}: a scenario must be a mapping")
    data.pop("derived", None)  # written by the simulator into truth/scenario.yaml
    return data


def _set(data: dict[str, Any], dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    node = data
    for k in keys[:-1]:
        node = node.setdefault(k, {})
        if not isinstance(node, dict):
            raise InputError(f"override {dotted}: {k} is not a section")
    node[keys[-1]] = value


def load_scenario(scenario: str | Path | SimConfig | None = None, **overrides: Any) -> SimConfig:
    """Named scenario / YAML file / SimConfig (None: defaults), then overrides: short names
    (stand, sensor, path, length_m, speed, seed, style, format, preview, ...), dotted keys given
    as `section__field` (e.g. terrain__relief_m=1.5), None values ignored; then the world
    style's presets fill the keys still unset (forestslam.sim.styles)."""
    if isinstance(scenario, SimConfig):
        data = to_dict(scenario)
        where = scenario.name
        style = overrides.get("style")
        if style is not None and str(style).lower() != scenario.style:
            raise InputError(
                f"{where}: a built SimConfig already has style {scenario.style!r}; give the "
                "style with the scenario name or file instead"
            )
    else:
        data = scenario_dict(scenario)
        where = str(scenario) if scenario is not None else "defaults"
        if scenario is not None and "name" not in data:
            data["name"] = Path(str(scenario)).stem
    for key, value in overrides.items():
        if value is None:
            continue
        dotted = ALIASES.get(key, key.replace("__", "."))
        _set(data, dotted, value)
    return from_dict(SimConfig, apply_style(data), where=where)
