"""Sensor profiles: shipped YAML files selectable by name, or a user's own YAML file."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "profile": ("SensorProfile", "available_profiles", "load_profile"),
    },
)
