"""The batch manifest: strict validation with errors naming the entry, paths and defaults."""

from pathlib import Path

import pytest

from forestslam.batch import load_manifest
from forestslam.batch.job import empty_row, fingerprint, finished_row
from forestslam.errors import InputError


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "manifest.yaml"
    path.write_text(text)
    return path


def test_entries_get_absolute_paths_and_defaults(tmp_path):
    recs = load_manifest(
        write(
            tmp_path,
            "recordings:\n"
            "  - {name: a, input: bags/a.bag, sensor: vlp16}\n"
            "  - {name: b.2, input: /data/b.bag, sensor: hdl32, truth: t, mode: map3d,"
            " start: 5, max_scans: 20, prior_map: stand.csv}\n",
        )
    )
    a, b = recs
    assert a.input == tmp_path / "bags" / "a.bag" and a.input.is_absolute()
    assert (a.mode, a.start, a.max_scans, a.truth, a.config, a.prior_map) == (
        "slam",
        0,
        None,
        None,
        None,
        None,
    )
    assert b.input == Path("/data/b.bag") and b.truth == tmp_path / "t"
    assert (b.sensor, b.mode, b.start, b.max_scans) == ("hdl32", "map3d", 5, 20)
    assert b.prior_map == tmp_path / "stand.csv"


@pytest.mark.parametrize(
    ("entries", "message"),
    [
        (
            "  - {name: a, input: a.bag, sensor: vlp16, colour: red}",
            r"recording 1 \('a'\): unknown key",
        ),
        ("  - {name: a, sensor: vlp16}", r"recording 1 \('a'\): missing input"),
        ("  - {input: a.bag, sensor: vlp16}", r"recording 1: missing name"),
        (
            "  - {name: a, input: a.bag, sensor: vlp16}\n"
            "  - {name: a, input: b.bag, sensor: vlp16}",
            r"recording 2: name 'a' is already used by recording 1",
        ),
        ("  - {name: a/b, input: a.bag, sensor: vlp16}", r"\('a/b'\): name must be"),
        ("  - {name: a, input: a.bag, sensor: vlp16, mode: fast}", r"\('a'\): unknown mode"),
        ("  - {name: a, input: a.bag, sensor: vlp99}", r"\('a'\): unknown sensor 'vlp99'"),
        ("  - {name: a, input: a.bag, sensor: vlp16, start: -1}", r"\('a'\): start must be"),
        ("  - {name: a, input: a.bag, sensor: vlp16, max_scans: 0}", r"max_scans must be"),
        ("  - {name: a, input: a.bag, sensor: vlp16, config: no.yaml}", r"configuration file"),
        ("  - just-a-string", r"recording 1: expected a mapping"),
    ],
)
def test_mistakes_name_the_entry(tmp_path, entries, message):
    with pytest.raises(InputError, match=message):
        load_manifest(write(tmp_path, "recordings:\n" + entries + "\n"))


@pytest.mark.parametrize(
    "text", ["", "recordings: []\n", "recording:\n  - {name: a}\n", "recordings: [\n"]
)
def test_a_manifest_without_recordings_is_an_error(tmp_path, text):
    with pytest.raises(InputError, match="manifest.yaml"):
        load_manifest(write(tmp_path, text))


def test_missing_manifest(tmp_path):
    with pytest.raises(InputError, match="manifest not found"):
        load_manifest(tmp_path / "none.yaml")


def test_finished_only_when_marker_matches_and_run_complete(tmp_path):
    """The resume rule, on hand-made run directories (no pipeline)."""
    import json

    config = tmp_path / "c.yaml"
    config.write_text("odometry: {method: trees}\n")
    manifest = write(
        tmp_path,
        "recordings:\n  - {name: a, input: a.bag, sensor: vlp16, truth: t, config: c.yaml}\n",
    )
    (rec,) = load_manifest(manifest)
    out = tmp_path / "out"
    run_dir = out / "a"
    run_dir.mkdir(parents=True)
    row = empty_row("a", "ok")
    (run_dir / "batch.json").write_text(json.dumps({"entry": fingerprint(rec), "row": row}))
    (run_dir / "run.yaml").write_text("summary: {status: running}\n")  # a killed run
    assert finished_row(rec, out) is None
    (run_dir / "run.yaml").write_text("summary: {status: complete}\n")
    assert finished_row(rec, out) is None  # truth given but no metrics.json
    (run_dir / "metrics.json").write_text("{}")
    assert finished_row(rec, out) == row
    config.write_text("odometry: {method: icp}\n")  # the configuration changed: redo
    assert finished_row(rec, out) is None


def test_a_binary_manifest_is_an_error(tmp_path):
    (tmp_path / "m.yaml").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(InputError, match="m.yaml: not a manifest .not UTF-8"):
        load_manifest(tmp_path / "m.yaml")
