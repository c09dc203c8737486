"""Root configuration: one section per component, each that component's own config dataclass.

A YAML file holds any subset of the sections, e.g.::

    slam:
      keyframe_distance_m: 0.5
    mapping:
      dbh_window_scans: 25

Missing sections and keys keep their defaults; an unknown section or key, a value of the wrong
type or out of its range is rejected naming the key (`forestslam.config_utils.from_dict`). The
run.yaml a job writes can be passed back as it is: its `config` section is read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from forestslam.config_utils import from_dict, read_yaml, to_dict
from forestslam.localization.config import LocalizationConfig
from forestslam.mapping.config import MappingConfig
from forestslam.multisession.loops import PlaceRecognitionConfig
from forestslam.multisession.prior import PriorMapConfig
from forestslam.odometry.config import OdometryConfig
from forestslam.perception.config import PerceptionConfig
from forestslam.slam.config import SlamConfig
from forestslam.tls.config import TlsConfig


@dataclass
class ForestSlamConfig:
    """Configuration of every forestslam component; field order is the order in run.yaml."""

    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    localization: LocalizationConfig = field(default_factory=LocalizationConfig)
    tls: TlsConfig = field(default_factory=TlsConfig)
    prior_map: PriorMapConfig = field(default_factory=PriorMapConfig)
    place_recognition: PlaceRecognitionConfig = field(default_factory=PlaceRecognitionConfig)


def load_config(path: str | Path | None = None) -> ForestSlamConfig:
    """The root config from a YAML file (or the `config` of a job's run.yaml), or the defaults
    when `path` is None; every value checked (`forestslam.config_utils`)."""
    if path is None:
        return ForestSlamConfig()
    data = read_yaml(path) or {}
    if isinstance(data, dict) and "summary" in data and isinstance(data.get("config"), dict):
        return from_dict(ForestSlamConfig, data["config"], where=f"{path}: config")
    return from_dict(ForestSlamConfig, data, where=f"{path}:")


def config_from_dict(data: dict | None) -> ForestSlamConfig:
    return from_dict(ForestSlamConfig, data)


def config_to_dict(config: ForestSlamConfig) -> dict:
    return to_dict(config)
