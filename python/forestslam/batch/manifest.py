"""The batch manifest: a YAML file with one `recordings:` entry per recording, validated strictly.

```yaml
recordings:
  - name: plot-a                # folder name of its run directory under --out
    input: bags/plot-a.bag      # bag / folder / cloud file, as `forestslam run` takes it
    sensor: vlp16               # profile name or profile YAML file
    truth: sim/plot-a/truth     # optional: simulator truth -> metrics.json
    mode: slam                  # optional: slam | map3d | odometry
    config: my.yaml             # optional: forestslam configuration
    start: 0                    # optional: skip this many scans first
    max_scans: 500              # optional: process at most N scans
    prior_map: stand.csv        # optional: prior tree map (when `forestslam run` supports it)
```

Relative paths are relative to the manifest's folder and are made absolute, so that workers on
other machines (sharing the file system) see the same files. Structure, names, modes, numbers,
sensors and configurations are checked here, before any work starts; whether a recording's files
exist or can be read is found out when it runs, and only that recording fails.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from forestslam.errors import ForestSlamError, InputError

KEYS = ("name", "input", "sensor", "truth", "mode", "config", "start", "max_scans", "prior_map")
REQUIRED = ("name", "input", "sensor")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
RESERVED_NAMES = ("summary.csv", "summary.md", "summary.png")


@dataclass(frozen=True)
class Recording:
    """One manifest entry with absolute paths and defaults filled in."""

    name: str
    input: Path
    sensor: str  # profile name, or the absolute path of a profile YAML file
    truth: Path | None = None
    mode: str = "slam"
    config: Path | None = None
    start: int = 0
    max_scans: int | None = None
    prior_map: Path | None = None

    def to_dict(self) -> dict:
        """Plain values (paths as strings), as written into batch.json."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in self.__dict__.items()}


def load_manifest(path: str | Path) -> list[Recording]:
    """The recordings of a manifest file; any mistake is an InputError naming file and entry."""
    import yaml

    from forestslam.io.text import read_input_text

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: manifest not found")
    try:
        data = yaml.safe_load(read_input_text(path, "manifest"))
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from exc
    if not isinstance(data, dict) or set(data) != {"recordings"}:
        found = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise InputError(f"{path}: expected one top-level key 'recordings:', found {found}")
    entries = data["recordings"]
    if not isinstance(entries, list) or not entries:
        raise InputError(f"{path}: 'recordings:' must be a non-empty list of entries")
    recordings: list[Recording] = []
    first_index: dict[str, int] = {}
    for i, entry in enumerate(entries, start=1):
        rec = _recording(entry, f"{path}: recording {i}", path.parent.resolve())
        if rec.name in first_index:
            raise InputError(
                f"{path}: recording {i}: name {rec.name!r} is already used by recording "
                f"{first_index[rec.name]}; names must be unique (they name the run folders)"
            )
        first_index[rec.name] = i
        recordings.append(rec)
    return recordings


def _recording(entry: object, where: str, base: Path) -> Recording:
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected a mapping with {', '.join(REQUIRED)}, not {entry!r}")
    name = entry.get("name")
    if isinstance(name, str):
        where = f"{where} ({name!r})"
    unknown = sorted(str(k) for k in entry if k not in KEYS)
    if unknown:
        raise InputError(
            f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(KEYS)}"
        )
    missing = [k for k in REQUIRED if entry.get(k) in (None, "")]
    if missing:
        raise InputError(f"{where}: missing {', '.join(missing)}")
    for key in ("name", "input", "sensor", "truth", "mode", "config", "prior_map"):
        if entry.get(key) is not None and not isinstance(entry[key], str):
            raise InputError(f"{where}: {key} must be a string, not {entry[key]!r}")
    if not NAME_PATTERN.match(name) or name in RESERVED_NAMES:
        raise InputError(
            f"{where}: name must be letters, digits, '.', '_' or '-' (a folder name), "
            f"not one of {', '.join(RESERVED_NAMES)}"
        )
    rec = Recording(
        name=name,
        input=_path(base, entry["input"]),
        sensor=_sensor(base, entry["sensor"]),
        truth=_path(base, entry.get("truth")),
        mode=entry.get("mode") or "slam",
        config=_path(base, entry.get("config")),
        start=_integer(entry, "start", 0, 0, where),
        max_scans=_integer(entry, "max_scans", None, 1, where),
        prior_map=_path(base, entry.get("prior_map")),
    )
    _check_settings(rec, where)
    return rec


def _path(base: Path, value: str | None) -> Path | None:
    return None if value is None else (base / Path(value).expanduser()).absolute()


def _sensor(base: Path, value: str) -> str:
    """Profile names stay names; a YAML file is resolved like the other paths."""
    return str(_path(base, value)) if Path(value).suffix in (".yaml", ".yml") else value


def _integer(entry: dict, key: str, default: int | None, minimum: int, where: str) -> int | None:
    value = entry.get(key)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(f"{where}: {key} must be an integer >= {minimum}, not {value!r}")
    return value


def _check_settings(rec: Recording, where: str) -> None:
    """Mode, sensor profile and configuration file: a mistake here would fail every scan."""
    from forestslam.config import load_config
    from forestslam.runner import MODES
    from forestslam.sensors import load_profile

    if rec.mode not in MODES:
        raise InputError(f"{where}: unknown mode {rec.mode!r}; choose one of {', '.join(MODES)}")
    try:
        load_profile(rec.sensor)
        if rec.config is not None:
            load_config(rec.config)
    except (ForestSlamError, OSError) as exc:
        raise InputError(f"{where}: {exc}") from exc
