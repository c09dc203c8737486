"""Simulated benchmark sequences, generated once into data/cache/sim/ (git-ignored)."""

from __future__ import annotations

import time
from pathlib import Path

CACHE = Path(__file__).resolve().parents[1] / "data" / "cache"


def sequence(name: str, max_scans: int | None) -> Path:
    """The cached simulator output of scenario `name` (first `max_scans` scans), made if missing."""
    from forestslam.sim import simulate

    tag = name if max_scans is None else f"{name}-{max_scans}"
    out = CACHE / "sim" / tag
    if not (out / "sequence.bag").is_file() or not (out / "truth" / "trajectory.tum").is_file():
        kw = {} if max_scans is None else {"max_scans": max_scans}
        t = time.perf_counter()
        simulate(name, out, **kw)
        print(f"  simulated {name} in {time.perf_counter() - t:.0f} s -> {out}", flush=True)
    return out


def sensor_of(seq: Path) -> str:
    """The sensor profile a cached sequence was simulated with."""
    import yaml

    doc = yaml.safe_load((seq / "truth" / "scenario.yaml").read_text())
    return doc["sensor"]["profile"]
