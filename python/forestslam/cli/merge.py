"""`forestslam merge RUN_A RUN_B --out DIR`: one tree map of two runs, in A's frame."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        "merge",
        help="Place run B's tree map in run A's frame (global localization plus refinement) and "
        "write the merged trees (fused DBH, observation counts, source a/b/both) and both "
        "trajectories in A's frame: trees.csv, trees.geojson, trajectory_a.tum, "
        "trajectory_b.tum, merge.yaml, map.png.",
    )
    def _command(
        run_a: Path = typer.Argument(
            ..., metavar="RUN_A", help="Run directory whose frame is kept."
        ),
        run_b: Path = typer.Argument(..., metavar="RUN_B", help="Run directory placed into A."),
        out: Path = typer.Option(..., "--out", help="Output directory."),
        overwrite: bool = typer.Option(
            False, "--overwrite", help="Replace the outputs of another command in OUT."
        ),
    ) -> None:
        from forestslam.multisession.runs import merge_runs

        s = merge_runs(run_a, run_b, out, overwrite=overwrite)
        print(
            f"B placed in A at x {s['x']:.3f} m, y {s['y']:.3f} m, yaw {s['yaw_deg']:.2f} deg "
            f"({s['agreeing_queries']} of {s['queries']} queries agree, {s['matched_trees']} "
            f"trees matched, rms {s['rms_m'] * 100:.1f} cm); {s['trees']['merged']} trees -> {out}"
        )
