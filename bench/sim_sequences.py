"""Simulated benchmark sequences, generated once into data/cache/sim/ (git-ignored)."""

from __future__ import annotations

import time
from pathlib import Path

CACHE = Path(__file__).resolve().parents[1] / "data" / "cache"


def sequence(name: str, max_scans: int | None, style: str | None = None) -> Path:
    """The cached simulator output of scenario `name` (first `max_scans` scans) in world style
    `style` (None: the scenario's own), made if missing. The tag carries the simulator's model
    version, so sequences made by an older simulator are never reused."""
    from forestslam.sim import simulate
    from forestslam.sim.simulate import MODEL_VERSION

    tag = f"{name}-m{MODEL_VERSION}" + (f"-{style}" if style else "")
    tag += "" if max_scans is None else f"-{max_scans}"
    out = CACHE / "sim" / tag
    if not (out / "sequence.bag").is_file() or not (out / "truth" / "trajectory.tum").is_file():
        kw = {} if max_scans is None else {"max_scans": max_scans}
        if style:
            kw["style"] = style
        t = time.perf_counter()
        simulate(name, out, **kw)
        print(f"  simulated {name} in {time.perf_counter() - t:.0f} s -> {out}", flush=True)
    return out


def sensor_of(seq: Path) -> str:
    """The sensor profile a cached sequence was simulated with."""
    import yaml

    doc = yaml.safe_load((seq / "truth" / "scenario.yaml").read_text())
    return doc["sensor"]["profile"]
