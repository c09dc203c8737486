"""The one way config crosses into the C++ core: every field of a config dataclass is copied onto
the typed pybind class of the C++ struct with the same field names (nested dataclasses onto
nested structs). A field the C++ struct lacks or a value of the wrong type is an InputError that
names the key; the defaults live in C++ (tests/test_config_parity.py checks both sides)."""

from __future__ import annotations

import dataclasses
from typing import Any

from forestslam.errors import InputError


def _check_type(key: str, value: Any, default: Any) -> None:
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = True  # lists and nested structs: pybind converts or raises below
    if not ok:
        raise InputError(f"{key}: {value!r} is not a {type(default).__name__}")


def fill_core(config: Any, core: Any, where: str, skip: tuple[str, ...] = ()) -> Any:
    """Copy the fields of dataclass `config` onto the pybind object `core`; returns `core`."""
    for f in dataclasses.fields(config):
        if f.name in skip:
            continue
        key = f"{where}.{f.name}"
        value = getattr(config, f.name)
        if not hasattr(core, f.name):
            raise InputError(f"{key}: no such option in the C++ core")
        if dataclasses.is_dataclass(value):
            setattr(core, f.name, fill_core(value, getattr(core, f.name), key))
            continue
        _check_type(key, value, getattr(core, f.name))
        try:
            setattr(core, f.name, value)
        except TypeError as exc:
            raise InputError(f"{key}: {value!r} has the wrong type ({exc})") from None
    return core
