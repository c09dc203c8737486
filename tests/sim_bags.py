"""Small sequences of the project's own simulator (the sample scenario), written once per
test session as a ROS1 bag or an MCAP file, for the tests of damaged and fuzzed input."""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

SCANS = 12  # ~370 kB each: rosbags writes ~3 per 1 MB chunk, so a bag has 4-5 chunks


@functools.cache
def sample_sequence(fmt: str = "bag", scans: int = SCANS) -> Path:
    """The path of a simulated sample sequence (bag or mcap) in a session temp folder."""
    from forestslam.sim.simulate import simulate

    out = Path(tempfile.mkdtemp(prefix=f"forestslam-sim-{fmt}-"))
    atexit.register(shutil.rmtree, out, ignore_errors=True)
    simulate("sample", out, max_scans=scans, format=fmt)
    return out / f"sequence.{fmt}"
