"""Package exports are imported on first use: the root config (read by every command, and by a
batch's manifest check before its cluster starts) does not pull in GTSAM, the C++ core or SciPy."""

from __future__ import annotations

import subprocess
import sys
import types

import pytest

from forestslam.lazy import lazy_exports

HEAVY = ("gtsam", "forestslam._core", "scipy.spatial", "matplotlib", "rosbags")


def test_the_root_config_imports_no_heavy_module():
    code = f"import sys, forestslam.config; print([m for m in {HEAVY!r} if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_exports_resolve_on_first_use_and_unknown_names_fail():
    from forestslam import slam
    from forestslam.slam.landmark_slam import LandmarkSlam

    assert slam.LandmarkSlam is LandmarkSlam and "LandmarkSlam" in dir(slam)
    assert "LandmarkSlam" in slam.__all__
    with pytest.raises(AttributeError, match="no attribute 'Nothing'"):
        _ = slam.Nothing


def test_an_export_named_like_a_submodule_is_refused():
    sys.modules["fake_pkg"] = types.ModuleType("fake_pkg")
    try:
        with pytest.raises(ValueError, match="named like its submodules: tool"):
            lazy_exports("fake_pkg", {"tool": ("tool",), "other": ("x",)})
    finally:
        del sys.modules["fake_pkg"]
