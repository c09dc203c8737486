"""`forestslam simulate`: a simulated forest LiDAR sequence (or TLS station) with ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        "simulate",
        help="Simulate a LiDAR sequence in a forest with ground truth (trajectory, trees). "
        "Start from a named scenario or YAML (--scenario) and override with flags.",
    )
    def simulate_command(
        out: Path = typer.Option(None, "--out", help="Output folder (required but with --list)."),
        scenario: str = typer.Option(
            None, "--scenario", help="Named scenario (sample, vlp16-loop, ...) or a YAML file."
        ),
        stand: str = typer.Option(
            None,
            "--stand",
            help="'generated', a stand name (longleaf, spruces) or a CSV x,y,dbh_m.",
        ),
        crop: str = typer.Option(
            None, "--crop", help="Crop of the stand: xmin,ymin,xmax,ymax (m)."
        ),
        sensor: str = typer.Option(None, "--sensor", help="Sensor profile name or YAML file."),
        path: str = typer.Option(
            None, "--path", help="loop | lawnmower | line | station | waypoint CSV (header x,y)."
        ),
        length_m: float = typer.Option(None, "--length-m", help="Path length (m)."),
        speed: float = typer.Option(None, "--speed", help="Speed (m/s)."),
        height_m: float = typer.Option(None, "--height-m", help="Sensor height above terrain (m)."),
        seed: int = typer.Option(None, "--seed", help="Random seed (same seed, same bytes)."),
        style: Literal["a", "b"] | None = typer.Option(
            None,
            "--style",
            help="World style a | b: stem, crown and intensity models (see the README).",
        ),
        fmt: Literal["bag", "mcap"] | None = typer.Option(
            None, "--format", help="bag (ROS1) or mcap (ROS2)."
        ),
        max_scans: int = typer.Option(None, "--max-scans", help="Stop after this many scans."),
        preview: bool = typer.Option(False, "--preview", help="Also write preview.png."),
        set_: list[str] = typer.Option(
            None, "--set", help="Any parameter as section.field=value, e.g. terrain.relief_m=1.5."
        ),
        list_scenarios: bool = typer.Option(False, "--list", help="List named scenarios and exit."),
    ) -> None:
        import time

        from forestslam.errors import InputError
        from forestslam.job import check_output_path
        from forestslam.sim import available_scenarios, simulate

        if list_scenarios:
            print("\n".join(available_scenarios()))
            return
        if out is None:
            raise InputError("missing option '--out' (the output folder)")
        check_output_path(out)  # before the simulation, not after it
        overrides: dict = {
            "stand": stand,
            "sensor": sensor,
            "path": path,
            "length_m": length_m,
            "speed": speed,
            "height_m": height_m,
            "seed": seed,
            "style": style,
            "format": fmt,
            "max_scans": max_scans,
            "preview": True if preview else None,
        }
        overrides.update(_crop(crop))
        overrides.update(_set_overrides(set_ or []))
        start = time.perf_counter()
        out_dir = simulate(scenario, out, progress=True, **overrides)
        _print_summary(out_dir, time.perf_counter() - start)


def _crop(crop: str | None) -> dict:
    """--crop xmin,ymin,xmax,ymax as the crop_m override (none without the flag)."""
    from forestslam.errors import InputError

    if crop is None:
        return {}
    try:
        values = [float(v) for v in crop.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise InputError(f"--crop {crop!r}: expected xmin,ymin,xmax,ymax")
    return {"crop_m": values}


def _set_overrides(items: list[str]) -> dict:
    """--set section.field=value items as simulate() overrides (section__field: value)."""
    from forestslam.config_utils import parse_yaml
    from forestslam.errors import InputError

    overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"--set {item!r}: expected section.field=value")
        overrides[key.strip().replace(".", "__")] = parse_yaml(value, f"--set {item!r}")
    return overrides


def _print_summary(out_dir: Path, elapsed: float) -> None:
    import yaml

    derived = yaml.safe_load((out_dir / "truth" / "scenario.yaml").read_text())["derived"]
    files = sorted(p.name for p in out_dir.iterdir() if p.is_file())
    print(
        f"{out_dir}: {derived['scans']} scans, {derived['duration_s']:.1f} s, path "
        f"{derived['path_length_m']:.1f} m, {derived['objects']['trees']} trees, "
        f"written in {elapsed:.1f} s ({', '.join(files)}, truth/)"
    )
