"""Fingerprints of simulated scans and truth files, to show that a change to the simulator's code
(a refactoring, a speed-up) leaves its output bit-identical.

    python bench/sim_fingerprint.py --out before.json [--scenarios vlp16-loop ...] [--scans 3]
    python bench/sim_fingerprint.py --out after.json --compare before.json

For each scenario and world style (a, b): SHA-256 of the points, intensity, ring and time of the
first `--scans` scans (with the per-point surface class and object), and of the truth files
(trajectory.tum, trees.csv, scenario.yaml without the package version). --compare prints every
differing entry and exits non-zero when there is one. Scenarios on stands in ../shared/data are
skipped when absent.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from forestslam.errors import InputError
from forestslam.sim.scenarios import load_scenario
from forestslam.sim.simulate import scan_at, write_truth
from forestslam.sim.world import build_world

SCENARIOS = ("vlp16-loop", "hdl32-loop", "rsm1-robot", "tls-plot")


def _digest(data: bytes | np.ndarray | None) -> str:
    if data is None:
        return "none"
    if isinstance(data, np.ndarray):
        data = np.ascontiguousarray(data).tobytes() + str((data.dtype, data.shape)).encode()
    return hashlib.sha256(data).hexdigest()[:16]


def _truth_digests(world) -> dict[str, str]:
    with tempfile.TemporaryDirectory() as tmp:
        write_truth(world, Path(tmp))
        out = {}
        for path in sorted((Path(tmp) / "truth").iterdir()):
            lines = path.read_text(encoding="utf-8").splitlines()
            # The package version is not the simulator's output.
            kept = [line for line in lines if "forestslam_version" not in line]
            out[f"truth/{path.name}"] = _digest("\n".join(kept).encode())
        return out


def fingerprint(name: str, style: str, n_scans: int) -> dict[str, str]:
    world = build_world(load_scenario(name, style=style))
    out = _truth_digests(world)
    for k in range(min(n_scans, len(world.stamps))):
        scan, surface, obj = scan_at(world, k, labels=True)
        out[f"scan{k}/n"] = str(len(scan))
        out[f"scan{k}/stamp"] = repr(scan.stamp)
        for field in ("points", "intensity", "ring", "time"):
            out[f"scan{k}/{field}"] = _digest(getattr(scan, field))
        out[f"scan{k}/surface"] = _digest(surface)
        out[f"scan{k}/object"] = _digest(obj)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--styles", nargs="+", default=["a", "b"])
    ap.add_argument("--scans", type=int, default=3)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--compare", type=Path)
    args = ap.parse_args()
    result: dict[str, dict[str, str]] = {}
    for name in args.scenarios:
        for style in args.styles:
            try:
                result[f"{name}/{style}"] = fingerprint(name, style, args.scans)
            except InputError as exc:
                print(f"{name}/{style}: skipped ({exc})")
                continue
            entries = result[f"{name}/{style}"]
            scans = sum(key.endswith("/n") for key in entries)
            print(f"{name}/{style}: {scans} scans, {len(entries)} digests")
    args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    if args.compare is None:
        return 0
    reference = json.loads(args.compare.read_text(encoding="utf-8"))
    differ = 0
    for key in sorted(set(reference) | set(result)):
        ref, new = reference.get(key, {}), result.get(key, {})
        for entry in sorted(set(ref) | set(new)):
            if ref.get(entry) != new.get(entry):
                differ += 1
                print(f"DIFFERS {key} {entry}: {ref.get(entry)} -> {new.get(entry)}")
    n = sum(len(v) for v in result.values())
    print(f"{n} digests compared with {args.compare}: {differ} differ")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
