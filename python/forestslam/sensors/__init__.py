"""Sensor profiles: shipped YAML files selectable by name, or a user's own YAML file."""

from forestslam.sensors.profile import SensorProfile, available_profiles, load_profile

__all__ = ["SensorProfile", "available_profiles", "load_profile"]
