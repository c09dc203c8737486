"""Config values are checked by type and range when loaded (issue 19, item 6): the error names
the key path, the value and what is allowed; YAML numbers are read as YAML 1.2 reads them."""

from __future__ import annotations

import pytest

from forestslam.config import ForestSlamConfig, config_from_dict, load_config
from forestslam.config_utils import parse_yaml, validate
from forestslam.errors import InputError


def load(tmp_path, text: str) -> ForestSlamConfig:
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    return load_config(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        # wrong types, each once a traceback or a silent nonsense value
        ("perception:\n  filter:\n    voxel_m: abc\n", r"filter.voxel_m: 'abc' .*a number"),
        ("perception:\n  filter:\n    voxel_m: true\n", r"voxel_m: True .*a number"),
        ("slam:\n  keyframe_distance_m: null\n", r"slam.keyframe_distance_m: None .*null"),
        ("slam:\n  keyframe_distance_m: .nan\n", r"keyframe_distance_m: nan .*finite"),
        ("mapping:\n  dbh_window_scans: 2.5\n", r"dbh_window_scans: 2.5 .*an integer"),
        ("odometry:\n  deskew: 1\n", r"odometry.deskew: 1 .*true or false"),
        # ranges
        ("mapping:\n  dbh_window_scans: 0\n", r"mapping.dbh_window_scans: 0 .*integer >= 1"),
        ("mapping:\n  checkpoint_every_scans: 0\n", r"checkpoint_every_scans: 0 .*>= 1"),
        (
            "odometry:\n  registration:\n    icp:\n      max_iterations: 0\n",
            r"odometry.registration.icp.max_iterations: 0 .*>= 1",
        ),
        ("perception:\n  ground_voxel_m: -0.2\n", r"ground_voxel_m: -0.2 .*> 0"),
        ("localization:\n  min_inlier_fraction: 1.5\n", r"min_inlier_fraction: 1.5 .*<= 1"),
        ("mapping:\n  dbh_band_m: [1.1, -1.0]\n", r"dbh_band_m\[1\]: -1.0 .*> 0"),
        ("mapping:\n  dbh_band_m: [1.1]\n", r"dbh_band_m: \[1.1\] .*a list of 2"),
        # enumerations list their choices
        ("slam:\n  robust_kernel: banana\n", r"robust_kernel: 'banana' .*huber, cauchy, none"),
        ("odometry:\n  method: kiss\n", r"odometry.method: 'kiss' .*trees, icp, fpfh"),
        ("odometry:\n  mode: mapping\n", r"odometry.mode: 'mapping' .*local_map, scan_to_scan"),
        ("tls:\n  registration:\n    initial_pose: gps\n", r"initial_pose: 'gps' .*ndt, velocity"),
        # structure
        ("slam: 3\n", r"slam: expected a mapping"),
        ("slam:\n  keyframe_distance: 1\n", r"unknown key\(s\) keyframe_distance"),
    ],
)
def test_bad_value_names_key_value_and_allowed(tmp_path, text, message):
    with pytest.raises(InputError, match=message) as info:
        load(tmp_path, text)
    assert str(info.value).startswith(str(tmp_path / "cfg.yaml"))  # the file is named


def test_yaml_12_numbers(tmp_path):
    cfg = load(tmp_path, "perception:\n  filter:\n    voxel_m: 1e-3\nmapping:\n  dbh_max_m: 2E+0\n")
    assert cfg.perception.filter.voxel_m == pytest.approx(1e-3)
    assert cfg.mapping.dbh_max_m == 2.0
    assert parse_yaml("a: 1e3\nb: 12\nc: -.5\nd: 1.5e3\ne: '1e3'\n", "x") == {
        "a": 1000.0,
        "b": 12,
        "c": -0.5,
        "d": 1500.0,
        "e": "1e3",  # quoted: a string
    }


def test_integral_float_is_an_integer_and_int_is_a_float(tmp_path):
    cfg = load(tmp_path, "mapping:\n  dbh_window_scans: 3e1\n  dbh_max_m: 2\n")
    assert cfg.mapping.dbh_window_scans == 30 and isinstance(cfg.mapping.dbh_window_scans, int)
    assert isinstance(cfg.mapping.dbh_max_m, float)


def test_non_utf8_file_is_one_clear_error(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("# Försök\nslam:\n  keyframe_distance_m: 0.5\n".encode("latin-1"))
    with pytest.raises(InputError, match=r"latin1.yaml: not a UTF-8 text file"):
        load_config(path)


def test_defaults_are_valid_and_validate_checks_configs_built_in_python():
    cfg = validate(ForestSlamConfig())
    assert cfg == ForestSlamConfig()
    cfg.mapping.dbh_window_scans = 0
    with pytest.raises(InputError, match=r"config.mapping.dbh_window_scans: 0"):
        validate(cfg)
    cfg = ForestSlamConfig()
    cfg.slam.robust_kernel = "Huber"  # case matters: one spelling per choice
    with pytest.raises(InputError, match="robust_kernel"):
        validate(cfg)


def test_dict_configs_are_checked_too():
    with pytest.raises(InputError, match=r"config.slam.robust_k: '1' .*a number"):
        config_from_dict({"slam": {"robust_k": "1"}})
    assert config_from_dict({"slam": {"robust_k": 2}}).slam.robust_k == 2.0


def test_a_jobs_run_yaml_is_a_config_file(tmp_path):
    """run.yaml holds the job's config under `config`; --config run.yaml reads that section."""
    import yaml

    from forestslam.config import config_to_dict

    cfg = ForestSlamConfig()
    cfg.slam.keyframe_distance_m = 0.75
    doc = {"command": "run", "input": "x.bag", "config": config_to_dict(cfg), "summary": {}}
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert load_config(path) == cfg
    doc["config"]["slam"]["robust_kernel"] = "banana"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"run.yaml: config.slam.robust_kernel: 'banana'"):
        load_config(path)


def test_numpy_numbers_are_numbers_but_numpy_bools_are_not():
    import numpy as np

    cfg = ForestSlamConfig()
    cfg.odometry.max_source_points = np.int64(800)
    cfg.odometry.source_voxel_m = np.float32(0.25)
    validate(cfg)
    assert type(cfg.odometry.max_source_points) is int
    assert type(cfg.odometry.source_voxel_m) is float
    cfg.odometry.source_voxel_m = np.bool_(True)
    with pytest.raises(InputError, match="source_voxel_m: .*a number"):
        validate(cfg)


def test_a_retired_key_of_an_earlier_run_yaml_is_logged_and_ignored(tmp_path, caplog):
    """An earlier version's run.yaml (localization.dbh_resolution_m, before the DBH likelihood
    ratio) still loads, says the key is ignored, and takes the current default; a key that was
    never valid is still an error."""
    with caplog.at_level("WARNING"):
        cfg = load(tmp_path, "localization:\n  dbh_resolution_m: 0.05\n")
    assert cfg.localization.dbh_sigma_m == ForestSlamConfig().localization.dbh_sigma_m
    assert "localization.dbh_resolution_m is retired and ignored" in caplog.text
    with pytest.raises(InputError, match="unknown key.*dbh_resolution_cm"):
        load(tmp_path, "localization:\n  dbh_resolution_cm: 0.05\n")
