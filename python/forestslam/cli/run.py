"""`forestslam run`: the main job (odometry, landmark SLAM, tree map, 3D ground map)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from forestslam.cli.options import ConfigFile, MaxScans, NoProgress, OutDir, Overwrite, Start, Topic

# The modes of forestslam.runner.MODES (kept here so the CLI loads without numpy; a test checks).
Mode = Literal["slam", "map3d", "odometry"]


def register(app: typer.Typer) -> None:
    @app.command(
        "run",
        help="Run odometry, tree SLAM and mapping on a bag / folder / cloud file and write "
        "trajectory.tum, odometry.tum, trees.csv, trees.geojson, trees.gpkg, map.laz, map.png, "
        "timing.json, run.yaml "
        "(map3d also ground.ply and dtm.*) into OUT. A re-run into OUT replaces the earlier "
        "run's outputs; OUT holding another command's outputs is refused without --overwrite.",
    )
    def _command(
        input_path: Path = typer.Argument(..., metavar="INPUT", help="Bag, folder or cloud file."),
        sensor: str | None = typer.Option(
            None,
            "--sensor",
            help="Sensor profile name or YAML file (default: identified from the data).",
        ),
        out: OutDir = ...,
        mode: Mode = typer.Option("slam", "--mode", help="What to build (see the README)."),
        config: ConfigFile = None,
        topic: Topic = None,
        start: Start = 0,
        max_scans: MaxScans = None,
        no_progress: NoProgress = False,
        overwrite: Overwrite = False,
        prior_map: Path | None = typer.Option(
            None,
            "--prior-map",
            help="Start in this tree map (a tree CSV x,y[,dbh_m] in any frame, a saved map "
            ".npz, or an earlier run's directory): outputs are in its frame once placed.",
        ),
        initial_pose: str | None = typer.Option(
            None, "--initial-pose", help="x,y,yaw_deg of the first scan in the prior map."
        ),
        inject_drift: str | None = typer.Option(
            None,
            "--inject-drift",
            help="scale,yaw_deg_per_10m: corrupt the odometry (tests and benches), e.g. 0.02,1.",
        ),
        crs: str | None = typer.Option(
            None, "--crs", help="Coordinate reference system of the outputs, e.g. EPSG:32633."
        ),
        georef: str | None = typer.Option(
            None, "--georef", help="x,y,z,yaw_deg: the first scan's pose in --crs (no prior map)."
        ),
        rerun: bool = typer.Option(False, "--rerun", help="Stream the run to a Rerun viewer."),
        rerun_save: Path | None = typer.Option(
            None, "--rerun-save", help="Record the Rerun view to this .rrd file instead."
        ),
    ) -> None:
        from forestslam.runner import run

        s = run(
            input_path,
            sensor,
            out,
            mode=mode,
            config_path=config,
            start=start,
            max_scans=max_scans,
            topic=topic,
            progress=not no_progress,
            overwrite=overwrite,
            prior_map=prior_map,
            initial_pose=initial_pose,
            inject_drift=inject_drift,
            crs=crs,
            georef=georef,
            rerun=rerun,
            rerun_save=rerun_save,
        )
        _print_summary(s)


def _print_summary(s) -> None:
    """One line: scans, speed, trees, degraded / failed scans, what the reader skipped."""
    rs = s.read_stats
    print(
        f"{s.scans} scans in {s.wall_s:.1f} s ({s.scans_per_s:.1f} scans/s; "
        f"{s.cpu_scans_per_s:.1f} per CPU second), "
        f"{s.trees} trees, {s.keyframes} keyframes, {s.degraded_scans} degraded, "
        f"{s.failed_scans} failed, {rs.get('skipped', 0)} corrupt messages skipped"
        + (f", {rs['lost_bytes']} bytes lost" if rs.get("lost_bytes") else "")
        + "".join(f", {n} {kind.replace('_', ' ')}" for kind, n in rs.get("degraded", {}).items())
        + (f", {s.loop_closures} loop closures" if s.loop_closures else "")
        + f" -> {s.out_dir}"
    )
