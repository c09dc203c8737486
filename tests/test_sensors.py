"""Sensor profiles: shipped ones by name with their documented geometry, user YAML files,
and a clear InputError for every kind of bad profile."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from forestslam.errors import InputError
from forestslam.sensors import available_profiles, load_profile


def test_shipped_profiles_load_by_name():
    assert {"vlp16", "hdl32", "os1-64", "rs-m1", "tls", "map"} <= set(available_profiles())
    for name in available_profiles():
        profile = load_profile(name)
        assert profile.name == name
        assert load_profile(profile) is profile


def test_documented_geometry():
    vlp = load_profile("vlp16")
    assert vlp.channels == 16 and vlp.kind == "spinning" and vlp.azimuth_resolution_deg == 0.2
    np.testing.assert_allclose(np.degrees(vlp.vertical_angles_rad), np.arange(-15, 16, 2))
    assert vlp.theta_v_rad == pytest.approx(np.radians(2.0))
    hdl = load_profile("hdl32")
    angles = np.degrees(hdl.vertical_angles_rad)
    assert len(angles) == 32 and angles[0] == pytest.approx(-30.67)
    assert angles[-1] == pytest.approx(10.67)
    rs = load_profile("rs-m1")
    assert (rs.kind, rs.image_rows, rs.image_cols) == ("solid_state", 127, 620)
    assert rs.horizontal_fov_deg == 120 and np.ptp(rs.vertical_fov_deg) == 25
    assert rs.has_range_image and not load_profile("map").has_range_image


def _vlp16_dict() -> dict:
    return load_profile("vlp16").to_dict()


def test_user_yaml_profile(tmp_path):
    data = _vlp16_dict() | {"name": "my-puck", "range_max_m": 40.0, "intensity_threshold": None}
    data["vertical_angles_deg"] = [float(a) for a in np.linspace(-10, 10, 16)[::-1]]
    path = tmp_path / "puck.yaml"
    path.write_text(yaml.safe_dump(data))
    profile = load_profile(path)
    assert profile.name == "my-puck" and profile.range_max_m == 40.0
    assert profile.intensity_threshold is None
    np.testing.assert_allclose(np.degrees(profile.vertical_angles_rad), np.linspace(-10, 10, 16))
    assert load_profile(str(path)) == profile


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"channels": "abc"}, "bad sensor profile value"),
        ({"channels": 2.5}, "integer"),
        ({"channels": -1}, "channels >= 1"),
        ({"rate_hz": 0}, "rate_hz > 0"),
        ({"rate_hz": 1e5}, "rate_hz <= 100"),  # a point rate or a period, not sweeps/s
        ({"dropout_rate": 1.5}, "dropout_rate"),
        ({"vertical_fov_deg": 5}, "bad sensor profile value"),
        ({"vertical_fov_deg": [10, -10]}, "low, high"),
        ({"kind": "radar"}, "kind must be one of"),
        ({"range_min_m": 50.0, "range_max_m": 10.0}, "range_min_m < range_max_m"),
        ({"vertical_angles_deg": [1.0, 2.0]}, "must list 16"),
        ({"colour": "red"}, "unknown keys"),
    ],
)
def test_bad_profiles(tmp_path, change, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_vlp16_dict() | change))
    with pytest.raises(InputError, match=message):
        load_profile(path)


def test_bad_files_and_names(tmp_path):
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(InputError, match="mapping"):
        load_profile(tmp_path / "list.yaml")
    (tmp_path / "syntax.yaml").write_text("name: [unclosed\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_profile(tmp_path / "syntax.yaml")
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(InputError, match="missing keys"):
        load_profile(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match="not found"):
        load_profile(tmp_path / "absent.yaml")
    with pytest.raises(InputError, match="unknown sensor 'vlp17'.*vlp16"):
        load_profile("vlp17")
