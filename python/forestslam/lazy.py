"""Lazy package exports (PEP 562).

A package's `__init__` names what it exports and from which submodule; the submodule is imported
on first use. So `from forestslam.slam.config import SlamConfig` (what the root config, the CLI's
argument checks and a batch's manifest check need) no longer imports GTSAM, PCL bindings and
SciPy through the package's `__init__`, while `from forestslam.slam import LandmarkSlam` works as
before.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable


def lazy_exports(
    package: str, exports: dict[str, tuple[str, ...]]
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """`__getattr__`, `__dir__` and `__all__` for `package`; `exports` maps a submodule (relative
    name, e.g. "config") to the names it provides."""
    where = {name: f"{package}.{module}" for module, names in exports.items() for name in names}
    clash = sorted(set(where) & set(exports))
    if clash:  # the import system would bind the submodule over the export, or the reverse
        raise ValueError(f"{package}: exports named like its submodules: {', '.join(clash)}")

    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where[name]), name)
        setattr(sys.modules[package], name, value)  # later lookups skip this function
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return __getattr__, __dir__, sorted(where)
