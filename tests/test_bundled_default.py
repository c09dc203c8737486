"""The bundled default (`make run`): data/sample.yaml is the packaged `sample` scenario."""

from pathlib import Path

from forestslam.sim import load_scenario

REPO = Path(__file__).resolve().parents[1]


def test_data_sample_is_the_packaged_sample_scenario():
    assert load_scenario(REPO / "data" / "sample.yaml") == load_scenario("sample")
