"""Root configuration: one section per component, each that component's own config dataclass.

A YAML file holds any subset of the sections, e.g.::

    slam:
      keyframe_distance_m: 0.5
    mapping:
      dbh_window_scans: 25

Missing sections and keys keep their defaults; an unknown section or key is rejected with the
list of valid names (`forestslam.config_utils.from_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from forestslam.config_utils import from_dict, load_yaml, to_dict
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
    """The root config from a YAML file, or the defaults when `path` is None."""
    if path is None:
        return ForestSlamConfig()
    return load_yaml(ForestSlamConfig, path)


def config_from_dict(data: dict | None) -> ForestSlamConfig:
    return from_dict(ForestSlamConfig, data)


def config_to_dict(config: ForestSlamConfig) -> dict:
    return to_dict(config)
