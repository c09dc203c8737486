"""Root configuration: one section per component, each that component's own config dataclass.

A YAML file holds any subset of the sections, e.g.::

    slam:
      keyframe_distance_m: 0.5
    mapping:
      dbh_window_scans: 25

Sections: perception, odometry, slam, mapping, localization, tls. Each comes from
`forestslam.<package>.config`; a component whose package is not part of this build (or not
yet) has no section, and a YAML file naming it is rejected with the list of valid sections.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
from pathlib import Path
from typing import Any

from forestslam.config_utils import from_dict, load_yaml, to_dict

log = logging.getLogger(__name__)

# (section, module, class name). The order is the order of the sections in run.yaml.
SECTIONS: tuple[tuple[str, str, str], ...] = (
    ("perception", "forestslam.perception.config", "PerceptionConfig"),
    ("odometry", "forestslam.odometry.config", "OdometryConfig"),
    ("slam", "forestslam.slam.config", "SlamConfig"),
    ("mapping", "forestslam.mapping.config", "MappingConfig"),
    ("localization", "forestslam.localization.config", "LocalizationConfig"),
    ("tls", "forestslam.tls.config", "TlsConfig"),
)


def _section_class(module_name: str, class_name: str) -> type | None:
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and module_name.startswith(exc.name):
            return None  # the component is not in this build
        raise
    cls = getattr(module, class_name, None)
    if cls is None or not dataclasses.is_dataclass(cls):
        log.debug("%s has no dataclass %s; section left out", module_name, class_name)
        return None
    return cls


def _build_root() -> type:
    fields = []
    for section, module_name, class_name in SECTIONS:
        cls = _section_class(module_name, class_name)
        if cls is not None:
            fields.append((section, cls, dataclasses.field(default_factory=cls)))
    root = dataclasses.make_dataclass("ForestSlamConfig", fields)
    root.__module__ = __name__
    sections = ", ".join(f[0] for f in fields)
    root.__doc__ = f"Configuration of every forestslam component (sections: {sections})."
    return root


ForestSlamConfig = _build_root()


def load_config(path: str | Path | None = None) -> Any:
    """The root config from a YAML file (missing sections and keys keep their defaults)."""
    if path is None:
        return ForestSlamConfig()
    return load_yaml(ForestSlamConfig, path)


def config_from_dict(data: dict | None) -> Any:
    return from_dict(ForestSlamConfig, data)


def config_to_dict(config: Any) -> dict:
    return to_dict(config)
