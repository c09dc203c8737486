"""Typed configuration: dataclasses built from nested dicts / YAML, every value checked.

Each field's type annotation is its contract: ``float`` takes a finite number (not a bool),
``int`` an integer (a float only when integral, e.g. ``1e3``), ``bool`` only true / false,
``Literal[...]`` one of its choices, ``X | None`` also null, ``tuple[...]`` a list of that many
items. Ranges sit next to the field as ``Annotated[float, Range(gt=0)]`` (aliases below), so the
default and its constraint are written once. ``from_dict`` / ``load_yaml`` build a checked
config; ``validate`` checks one built in Python. Errors name the key path, the value and what
is allowed.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import numbers
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import yaml

from forestslam.errors import InputError

T = TypeVar("T")
_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Range:
    """Bounds of a number (or of every item of a tuple of numbers); None = unbounded."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None

    def describe(self) -> str:
        bounds = ((">", self.gt), (">=", self.ge), ("<", self.lt), ("<=", self.le))
        return " and ".join(f"{op} {v:g}" for op, v in bounds if v is not None)

    def holds(self, v: float) -> bool:
        return not (
            (self.gt is not None and not v > self.gt)
            or (self.ge is not None and not v >= self.ge)
            or (self.lt is not None and not v < self.lt)
            or (self.le is not None and not v <= self.le)
        )


# Field types with their ranges; a config file reads e.g. `voxel_m: Positive = 0.05`.
Positive = Annotated[float, Range(gt=0)]
NonNegative = Annotated[float, Range(ge=0)]
Fraction = Annotated[float, Range(ge=0, le=1)]
PositiveInt = Annotated[int, Range(ge=1)]
NonNegativeInt = Annotated[int, Range(ge=0)]


# --------------------------------------------------------------------------------- checking
def _fail(where: str, value: Any, allowed: str) -> InputError:
    return InputError(f"{where}: {value!r} is not allowed; expected {allowed}")


def _key(where: str, name: str) -> str:
    """Key path of field `name` under `where` ('file.yaml:' roots a path in a file)."""
    return f"{where} {name}" if where.endswith(":") else f"{where}.{name}"


def _check_number(hint: type, value: Any, where: str) -> Any:
    """A Python or numpy number as `hint` (float / int); bools are not numbers here."""
    name = "an integer" if hint is int else "a number"
    is_bool = isinstance(value, bool) or type(value).__name__ == "bool_"  # numpy's too
    if is_bool or not isinstance(value, numbers.Real):
        raise _fail(where, value, name)
    if not math.isfinite(value):
        raise _fail(where, value, f"a finite {name.split()[-1]}")
    if hint is float:
        return float(value)
    if not isinstance(value, numbers.Integral) and not float(value).is_integer():
        raise _fail(where, value, name)
    return int(value)


def _check_tuple(args: tuple, value: Any, where: str, ranges: list[Range]) -> tuple:
    if not isinstance(value, list | tuple):
        raise _fail(where, value, f"a list of {len(args)} values")
    if len(args) == 2 and args[1] is Ellipsis:
        args = (args[0],) * len(value)
    if len(value) != len(args):
        raise _fail(where, value, f"a list of {len(args)} values")
    return tuple(
        check_value(Annotated[(a, *ranges)] if ranges else a, v, f"{where}[{i}]")
        for i, (a, v) in enumerate(zip(args, value, strict=True))
    )


def check_value(hint: Any, value: Any, where: str) -> Any:
    """`value` converted to field type `hint` (see the module docstring), or an InputError."""
    ranges: list[Range] = []
    if typing.get_origin(hint) is Annotated:
        hint, *meta = typing.get_args(hint)
        ranges = [m for m in meta if isinstance(m, Range)]
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) != 1:  # e.g. Literal["auto"] | tuple[...]: the first that takes it
            for option in options:
                try:
                    return check_value(option, value, where)
                except InputError:
                    continue
            raise _fail(where, value, " or ".join(_describe(o) for o in options))
        return check_value(Annotated[(options[0], *ranges)] if ranges else options[0], value, where)
    if value is None:
        raise _fail(where, value, f"{_describe(hint)} (null is not allowed)")
    if dataclasses.is_dataclass(hint):
        return validate(value, where) if isinstance(value, hint) else from_dict(hint, value, where)
    if origin is Literal:
        if not any(type(value) is type(a) and value == a for a in args):
            raise _fail(where, value, "one of " + ", ".join(map(str, args)))
        return value
    if origin is tuple:
        return _check_tuple(args, value, where, ranges)
    if hint is bool:
        if not isinstance(value, bool):
            raise _fail(where, value, "true or false")
        return value
    if hint in (int, float):
        value = _check_number(hint, value, where)
        for r in ranges:
            if not r.holds(value):
                raise _fail(where, value, f"{_describe(hint)} {r.describe()}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise _fail(where, value, "a string")
        return value
    if hint is Path:
        if not isinstance(value, str | Path):
            raise _fail(where, value, "a path")
        return Path(value)
    raise TypeError(f"{where}: unsupported field type {hint}")


def _describe(hint: Any) -> str:
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(hint)))
    names = {float: "a number", int: "an integer", bool: "true or false", str: "a string"}
    if typing.get_origin(hint) is tuple:
        return "a list"
    return names.get(hint, "a mapping" if dataclasses.is_dataclass(hint) else str(hint))


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def validate(obj: T, where: str = "config") -> T:
    """Check (and normalise, e.g. int -> float) every field of config dataclass `obj` in place;
    the one gate before a config reaches the core. Returns `obj`."""
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        setattr(obj, f.name, check_value(hints[f.name], getattr(obj, f.name), _key(where, f.name)))
    return obj


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass `cls` from `data`; nested dataclass fields recurse; unknown keys, wrong
    types and values out of range raise InputError naming the key."""
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise InputError(f"{where.rstrip(':')}: expected a mapping, got {type(data).__name__}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    data = _without_retired_keys(cls, data, where)
    unknown = sorted(set(data) - set(fields), key=str)
    if unknown:
        names, valid = ", ".join(map(str, unknown)), ", ".join(fields)
        raise InputError(f"{where.rstrip(':')}: unknown key(s) {names}; valid: {valid}")
    kwargs = {k: check_value(hints[k], v, _key(where, k)) for k, v in data.items()}
    return cls(**kwargs)


def _without_retired_keys(cls: type, data: dict[str, Any], where: str) -> dict[str, Any]:
    """`data` without the keys `cls.RETIRED_KEYS` names (key -> what replaced it), each logged:
    an earlier run's run.yaml still loads after a key was renamed or dropped, and the user is
    told its value is no longer read (never silently mapped onto a key that means another
    thing)."""
    retired: dict[str, str] = getattr(cls, "RETIRED_KEYS", {})
    for key in sorted(set(data) & set(retired), key=str):
        _log.warning("%s is retired and ignored: %s", _key(where, key), retired[key])
    return {k: v for k, v in data.items() if k not in retired}


def to_dict(obj: Any) -> dict[str, Any]:
    """Plain nested dict of a config dataclass (tuples become lists, for YAML)."""

    def plain(v: Any) -> Any:
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, Path):
            return str(v)
        return v

    return plain(dataclasses.asdict(obj))


# --------------------------------------------------------------------------------- YAML
class Yaml12Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats without a dot (`1e-3`, `2E+5`), which the
    YAML 1.1 resolver of PyYAML leaves as strings although every user means a number."""


Yaml12Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?$"),
    list("-+.0123456789"),
)


def parse_yaml(text: str, where: str) -> Any:
    """YAML text -> Python data with YAML 1.2 numbers; a syntax error is an InputError."""
    try:
        return yaml.load(text, Loader=Yaml12Loader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        raise InputError(f"{where}: not valid YAML ({exc})") from exc


def read_yaml(path: str | Path) -> Any:
    """A YAML file's data (YAML 1.2 numbers); missing, unreadable or non-UTF-8: InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: configuration file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        msg = f"{path}: not a UTF-8 text file (bad byte at offset {exc.start}); save it as UTF-8"
        raise InputError(msg) from exc
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from exc
    return parse_yaml(text, str(path))


def load_yaml(cls: type[T], path: str | Path) -> T:
    return from_dict(cls, read_yaml(path) or {}, where=f"{path}:")
