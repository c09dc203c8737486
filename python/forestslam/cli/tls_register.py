"""`forestslam tls-register INPUT --reference REF --sensor P --out DIR`."""

from __future__ import annotations

from pathlib import Path

import typer

from forestslam.cli.options import MaxScans, NoProgress, OutDir, Overwrite, Start, Topic


def register(app: typer.Typer) -> None:
    @app.command(
        "tls-register",
        help="Register a mobile (MLS) sequence onto a terrestrial (TLS) reference scan with "
        "stem-centre and DoG features (Shao et al. 2020) and merge them. Writes "
        "DIR/trajectory.tum (MLS poses in the TLS frame), DIR/plot.laz (merged cloud), "
        "DIR/trees.csv (id,x,y,z,dbh_m,dbh_std_m,observations), DIR/coverage.json (stem "
        "circumference covered at breast height, TLS alone vs merged), DIR/unmerged.csv "
        "(stamp,has_pose,reason of every frame that did not join the map) and DIR/plot.png. "
        "Without --initial-pose the walk is placed by matching the stems of its first frames "
        "(chained by odometry) to the reference's; later frames are tried until one is placed.",
    )
    def _command(
        input: Path = typer.Argument(..., help="MLS bag (.bag/.mcap) or folder of scans."),
        reference: Path = typer.Option(
            ...,
            "--reference",
            help="TLS reference: a cloud file (.laz/.las/.ply/.pcd/.npy) "
            "or a bag holding one scan.",
        ),
        sensor: str = typer.Option(..., "--sensor", help="MLS profile name or YAML (vlp16...)."),
        out: OutDir = ...,
        initial_pose: str | None = typer.Option(
            None,
            "--initial-pose",
            help="First MLS pose in the TLS frame: x,y,yaw_deg or x,y,z,yaw_deg.",
        ),
        topic: Topic = None,
        config: Path | None = typer.Option(None, "--config", help="YAML (tls section)."),
        start: Start = 0,
        max_scans: MaxScans = None,
        no_progress: NoProgress = False,
        overwrite: Overwrite = False,
    ) -> None:
        from forestslam.config import load_config
        from forestslam.tls.runner import parse_initial_pose, run_tls_register

        cfg = load_config(config).tls
        pose = parse_initial_pose(initial_pose)
        summary = run_tls_register(
            input,
            reference,
            sensor,
            out,
            cfg,
            pose,
            topic=topic,
            start=start,
            max_scans=max_scans,
            progress=not no_progress,
            overwrite=overwrite,
        )
        print(
            f"{summary['frames']} frames registered ({summary['accepted']} joined the map), "
            f"{summary['stems']} stems, map {summary['map_points']} points, "
            f"features+LM {summary['ms_features_lm_mean']:.1f} ms/frame"
        )
        if summary["coverage_tls"] is not None:
            print(
                f"stem circumference covered at breast height: TLS alone "
                f"{summary['coverage_tls']:.0%}, merged {summary['coverage_merged']:.0%}"
            )
        if summary["unmerged"]:
            kinds = "; ".join(f"{n} {kind}" for kind, n in summary["unmerged"].items())
            print(f"frames not merged: {kinds}")
        print(
            f"wrote {out}/trajectory.tum plot.laz trees.csv coverage.json unmerged.csv plot.png "
            "run.yaml"
        )
