"""The CLI's thread policy: one thread per numerical library unless the user set one, applied
before numpy loads (the CLI modules import it lazily), so no BLAS pool spins beside the job."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from forestslam.cli.main import LIBRARY_THREAD_VARS

PROBE = """
import os, sys
from forestslam.cli import main
assert "numpy" not in sys.modules, "the CLI imported numpy before its thread policy"
main.limit_library_threads()
import numpy
numpy.ones((2000, 3)) @ numpy.eye(3)  # a BLAS call
status = open("/proc/self/status").read()
threads = int(status.split("Threads:")[1].split()[0])
print(threads, *(os.environ[v] for v in main.LIBRARY_THREAD_VARS))
"""


def _probe(**env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in LIBRARY_THREAD_VARS}
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_one_thread_per_library_by_default():
    threads, *values = _probe()
    assert values == ["1"] * len(LIBRARY_THREAD_VARS)
    assert threads == "1"  # no OpenBLAS pool beside the main thread


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_a_users_explicit_setting_is_kept():
    _, openblas, omp, mkl = _probe(OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="3")
    assert (openblas, omp, mkl) == ("2", "3", "1")
