"""The one way config crosses into the C++ core (issue 18).

Every C++ option struct is bound once as a typed class whose attributes are its fields
(python/forestslam/pybind, ``FS_FIELD``); its defaults live only in C++. Python fills such an
object field by field here: ``fill_core`` copies a config dataclass with the same field names
(nested dataclasses onto nested structs), ``core_struct`` builds one from values known only at
the call (a height band, a round count). A field the C++ struct lacks or a value of the wrong
type is an InputError naming the key. tests/test_config_parity.py checks that the Python
dataclasses have the C++ fields and defaults.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
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
        ok = True  # arrays, enums and nested structs: pybind converts or raises below
    if not ok:
        raise InputError(f"{key}: {value!r} is not a {type(default).__name__}")


def set_field(core: Any, name: str, value: Any, where: str) -> None:
    """core.<name> = value, checked: the field must exist and the value have its type."""
    key = f"{where}.{name}"
    if not hasattr(core, name):
        raise InputError(f"{key}: no such option in the C++ core ({type(core).__name__})")
    _check_type(key, value, getattr(core, name))
    try:
        setattr(core, name, value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{key}: {value!r} has the wrong type or shape ({exc})") from None


def fill_core(config: Any, core: Any, where: str, skip: tuple[str, ...] = ()) -> Any:
    """Copy the fields of dataclass `config` (except `skip`) onto the pybind object `core`;
    nested dataclasses fill the nested structs. Returns `core`."""
    for f in dataclasses.fields(config):
        if f.name in skip:
            continue
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            key = f"{where}.{f.name}"
            if not hasattr(core, f.name):
                raise InputError(f"{key}: no such option in the C++ core")
            setattr(core, f.name, fill_core(value, getattr(core, f.name), key))
        else:
            set_field(core, f.name, value, where)
    return core


def core_struct(name: str, values: Mapping[str, Any], where: str) -> Any:
    """A new ``forestslam._core.<name>`` (C++ defaults) with `values` (C++ field names) set."""
    from forestslam import _core

    core = getattr(_core, name)()
    for field_name, value in values.items():
        set_field(core, field_name, value, where)
    return core


def renamed(config: Any, names: Mapping[str, str]) -> dict[str, Any]:
    """{C++ field: value} of the dataclass fields `names` maps (Python field -> C++ field): for a
    Python section that feeds several C++ structs or prefixes their fields (e.g. lm_*)."""
    return {cpp: getattr(config, py) for py, cpp in names.items()}


def prefixed(config: Any, prefix: str) -> dict[str, str]:
    """The name map of every field of dataclass `config` named ``<prefix><C++ field>``."""
    return {
        f.name: f.name[len(prefix) :]
        for f in dataclasses.fields(config)
        if f.name.startswith(prefix)
    }
