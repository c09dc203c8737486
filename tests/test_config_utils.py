"""Typed configuration loading: nested dataclasses from YAML, unknown keys rejected."""

from dataclasses import dataclass, field

import pytest

from forestslam.config_utils import from_dict, load_yaml, to_dict
from forestslam.errors import InputError


@dataclass
class Inner:
    radius_m: float = 0.5
    bounds: tuple[float, float] = (0.05, 0.6)


@dataclass
class Outer:
    name: str = "a"
    inner: Inner = field(default_factory=Inner)


def test_nested_dict_builds_typed_config():
    cfg = from_dict(Outer, {"name": "b", "inner": {"radius_m": 2.0, "bounds": [0.1, 0.2]}})
    assert cfg.name == "b"
    assert cfg.inner.radius_m == 2.0
    assert cfg.inner.bounds == (0.1, 0.2)


def test_unknown_key_names_the_key_and_path():
    with pytest.raises(InputError, match=r"config\.inner: unknown key\(s\) radius"):
        from_dict(Outer, {"inner": {"radius": 1.0}})


def test_yaml_round_trip(tmp_path):
    import yaml

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(to_dict(Outer(name="z", inner=Inner(radius_m=3.0)))))
    assert load_yaml(Outer, path) == Outer(name="z", inner=Inner(radius_m=3.0))


def test_missing_yaml_is_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_yaml(Outer, tmp_path / "nope.yaml")
