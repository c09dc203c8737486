"""A LiDAR's geometry, noise and range-image layout, as the simulator and perception need it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from forestslam.errors import InputError

KINDS = ("spinning", "solid_state", "tls", "map")


@dataclass(frozen=True)
class SensorProfile:
    """Vertical angles are `channels` beams evenly spread over `vertical_fov_deg` unless
    `vertical_angles_deg` lists them. `intensity_threshold` None means the sensor has no
    usable intensity (the intensity filter is skipped). `packet_model` names the Velodyne model
    whose raw packets (pcap, VelodyneScan) this profile decodes (None: the packets' factory byte
    tells), and `cut_angle_deg` the azimuth where a packet stream is cut into scans."""

    name: str
    kind: str
    channels: int
    vertical_fov_deg: tuple[float, float]
    horizontal_fov_deg: float
    azimuth_resolution_deg: float
    rate_hz: float
    range_min_m: float
    range_max_m: float
    range_noise_m: float
    dropout_rate: float
    image_rows: int
    image_cols: int
    intensity_threshold: float | None
    vertical_angles_deg: tuple[float, ...] | None = None
    packet_model: str | None = None
    cut_angle_deg: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"sensor {self.name}: kind must be one of {KINDS}, not {self.kind!r}")
        if not 0 <= self.range_min_m < self.range_max_m:
            raise InputError(f"sensor {self.name}: need 0 <= range_min_m < range_max_m")
        if self.vertical_angles_deg is not None and len(self.vertical_angles_deg) != self.channels:
            raise InputError(f"sensor {self.name}: vertical_angles_deg must list {self.channels}")

    @property
    def vertical_angles_rad(self) -> np.ndarray:
        """(channels,) beam elevations in radians, ascending."""
        if self.vertical_angles_deg is not None:
            return np.sort(np.radians(np.asarray(self.vertical_angles_deg, dtype=np.float64)))
        lo, hi = self.vertical_fov_deg
        return np.radians(np.linspace(lo, hi, self.channels))

    @property
    def theta_v_rad(self) -> float:
        """Vertical angular resolution (mean beam spacing), radians: the paper's theta_V."""
        if self.channels < 2:
            return float(np.radians(self.azimuth_resolution_deg))
        return float(np.mean(np.diff(self.vertical_angles_rad)))

    @property
    def has_range_image(self) -> bool:
        return self.kind in ("spinning", "solid_state") and self.image_rows > 0

    def packet_config(self):
        """How raw Velodyne packets of this sensor are decoded (forestslam.io.velodyne)."""
        from forestslam.io.velodyne import PacketConfig

        return PacketConfig(model=self.packet_model, cut_angle_deg=self.cut_angle_deg)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["vertical_fov_deg"] = list(self.vertical_fov_deg)
        if self.vertical_angles_deg is not None:
            d["vertical_angles_deg"] = list(self.vertical_angles_deg)
        return d


def available_profiles() -> list[str]:
    folder = resources.files("forestslam.sensors") / "profiles"
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def _from_mapping(data: dict, where: str) -> SensorProfile:
    fields = {f.name for f in dataclasses.fields(SensorProfile)}
    unknown = sorted(set(data) - fields)
    missing = sorted(
        f.name
        for f in dataclasses.fields(SensorProfile)
        if f.name not in data and f.default is dataclasses.MISSING
    )
    if unknown or missing:
        raise InputError(f"{where}: unknown keys {unknown}, missing keys {missing}")
    data = dict(data)
    try:
        data["name"] = str(data["name"])
        data["kind"] = str(data["kind"])
        for key in _INT_KEYS:
            value = data[key]
            if isinstance(value, bool) or int(value) != float(value):
                raise ValueError(f"{key} must be an integer, not {value!r}")
            data[key] = int(value)
        for key in _FLOAT_KEYS:
            data[key] = float(data[key])
        if data["intensity_threshold"] is not None:
            data["intensity_threshold"] = float(data["intensity_threshold"])
        fov = tuple(float(v) for v in data["vertical_fov_deg"])
        if len(fov) != 2 or not fov[0] <= fov[1]:
            raise ValueError(f"vertical_fov_deg must be [low, high], not {fov}")
        data["vertical_fov_deg"] = fov
        if data.get("packet_model") is not None:
            data["packet_model"] = str(data["packet_model"])
        if data.get("cut_angle_deg") is not None:
            data["cut_angle_deg"] = float(data["cut_angle_deg"])
        if data.get("vertical_angles_deg") is not None:
            data["vertical_angles_deg"] = tuple(float(v) for v in data["vertical_angles_deg"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: bad sensor profile value ({exc})") from None
    scanning = data["kind"] in ("spinning", "solid_state")
    bad = [
        text
        for ok, text in (
            (data["channels"] >= (1 if scanning else 0), "channels >= 1"),
            (data["rate_hz"] > 0 if scanning else data["rate_hz"] >= 0, "rate_hz > 0"),
            (data["rate_hz"] <= MAX_RATE_HZ, f"rate_hz <= {MAX_RATE_HZ:g} (sweeps per second)"),
            (data["azimuth_resolution_deg"] > 0, "azimuth_resolution_deg > 0"),
            (0 < data["horizontal_fov_deg"] <= 360, "0 < horizontal_fov_deg <= 360"),
            (data["range_noise_m"] >= 0, "range_noise_m >= 0"),
            (0 <= data["dropout_rate"] < 1, "0 <= dropout_rate < 1"),
            (data["image_rows"] >= 0 and data["image_cols"] >= 0, "image size >= 0"),
            (0 <= (data.get("cut_angle_deg") or 0.0) < 360, "0 <= cut_angle_deg < 360"),
        )
        if not ok
    ]
    if bad:
        raise InputError(f"{where}: sensor profile needs {', '.join(bad)}")
    return SensorProfile(**data)


MAX_RATE_HZ = 100.0  # no spinning or solid-state LiDAR sweeps faster: a period or a point rate
_INT_KEYS = ("channels", "image_rows", "image_cols")
_FLOAT_KEYS = (
    "horizontal_fov_deg",
    "azimuth_resolution_deg",
    "rate_hz",
    "range_min_m",
    "range_max_m",
    "range_noise_m",
    "dropout_rate",
)


def _load_yaml(text: str, where: str) -> dict:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0]
        raise InputError(f"{where}: not valid YAML ({first})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"{where}: a sensor profile must be a YAML mapping of keys to values")
    return data


def load_profile(name_or_path: str | Path | SensorProfile) -> SensorProfile:
    """A shipped profile by name (vlp16, hdl32, os1-64, rs-m1, tls, map) or a YAML file."""
    if isinstance(name_or_path, SensorProfile):
        return name_or_path
    text = str(name_or_path)
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise InputError(f"{path}: sensor profile file not found")
        from forestslam.io.text import read_input_text

        text = read_input_text(path, "sensor profile")
        return _from_mapping(_load_yaml(text, str(path)), str(path))
    if text not in available_profiles():
        raise InputError(
            f"unknown sensor {text!r}; shipped: {', '.join(available_profiles())}"
            " (or give a profile YAML file)"
        )
    resource = resources.files("forestslam.sensors") / "profiles" / f"{text}.yaml"
    return _from_mapping(_load_yaml(resource.read_text(), text), text)
